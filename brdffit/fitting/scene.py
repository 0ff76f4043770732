"""Which direction pairs a scene uses, as a weight per MERL bin.

A renderer only ever evaluates a material at the (light, view) pairs its scene
produces. A :class:`Scene` says which, in the local shading frame (normal +z,
directions pointing away from the surface), and :meth:`Scene.bin_weight` turns
that into one weight per MERL bin for ``fit(..., bin_weight=...)``: the loss,
the reported error and the model selection then count only those bins.

Three ways to describe a scene, combinable (the weights multiply):

- angle limits: ``max_theta_i`` / ``max_theta_o`` in **degrees** (a bin counts when
  its centre is within both; by reciprocity a bin also stands for the swapped
  pair, so either orientation qualifies);
- direction pairs ``pairs`` (N, 2, 3): (wi, wo) the scene uses, each spread over a
  cone of ``spread`` degrees (a few pairs would otherwise touch only a few bins);
  a bin's weight is then its share of the pairs, per unit solid angle, so that the
  fit's loss weights (solid angle x scene) are the pairs' own distribution;
- a preset: ``camera-normal`` (a camera looking along the normal, within 10
  degrees; lights anywhere), e.g. a flat material photographed head-on.

Files (``Scene.from_file``), documented with examples in docs/selection.md:

- ``.npy``: an array of pairs, shape (N, 6) or (N, 2, 3): wi_x, wi_y, wi_z, wo_x, wo_y, wo_z;
- ``.csv``: the same six columns, one pair per line; a header line and ``#``
  comments are skipped;
- ``.json``: an object with any of ``preset``, ``max_theta_i``, ``max_theta_o``,
  ``pairs`` ([[wi, wo], ...]), ``lights`` and ``views`` (every light with every
  view), ``pairs_file`` (a .npy/.csv path, relative to the JSON file),
  ``spread``, ``name``.

Directions need not be unit length (they are normalised); pairs with a direction
at or below the horizon are dropped and counted in :attr:`Scene.dropped_pairs`.
"""

from __future__ import annotations

import functools
import json
import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from brdffit import runtime
from brdffit.errors import FitInputError
from brdffit.io.angles import dirs_to_half_diff, flat_index, half_diff_to_bins
from brdffit.io.grid import bin_grid

#: Named scenes: keyword arguments of :class:`Scene`.
PRESETS: dict[str, dict] = {
    # A camera on the normal sees a flat sample within its half field of view
    # (~10 deg for a normal lens); the light may come from anywhere.
    "camera-normal": {"max_theta_o": 10.0},
}

#: Jittered copies per pair are capped so that a scene costs at most ~this many lookups.
_MAX_LOOKUPS = 400_000


#: The longest scene name (a file name's 255, as the service's table names).
MAX_NAME = 255

#: The most direction pairs a scene may hold (``lights`` x ``views`` counted as their
#: product). A scene is binned onto the table's 1.46M bins, so more pairs add little
#: but memory: 9M pairs (3,000 lights with 3,000 views, a 142 KB file) took 2.3 GB.
MAX_PAIRS = 2_000_000


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)  # True is not 1 degree


class SceneError(FitInputError):
    """A scene description that cannot be used (explained in the message)."""


@dataclass(frozen=True, eq=False)
class Scene:
    """The directions a scene uses; see the module docstring."""

    max_theta_i: float = 90.0
    max_theta_o: float = 90.0
    pairs: np.ndarray | None = None  # (N, 2, 3), unit, above the horizon
    spread: float = 2.0
    name: str = "custom"
    dropped_pairs: int = 0
    extra: dict = field(default_factory=dict)
    # the lights and the views whose every pairing ``pairs`` holds, where it was given
    # so and nothing else: kept so, a request stores 2 x 141 directions where the
    # pairs were 19,881 (a 2.5 MB job record, and a client's body over the service's
    # cap). Set by from_dict alone: a scene made otherwise (dataclasses.replace with
    # other pairs) has none, and lists its pairs
    lights_views: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False)

    def __post_init__(self):
        for k in ("max_theta_i", "max_theta_o"):
            v = getattr(self, k)
            if not (_is_number(v) and 0.0 < v <= 90.0):
                raise SceneError(f"scene {k} must be in (0, 90] degrees, got {v!r}")
        if not (_is_number(self.spread) and 0.0 <= self.spread <= 45.0):
            raise SceneError(f"scene spread must be in [0, 45] degrees, got {self.spread!r}")
        # the name is in every result, job and batch file that uses the scene: a
        # 100,000-character one made a 508 KB job record
        if not isinstance(self.name, str) or not 0 < len(self.name) <= MAX_NAME:
            shown = (f"{len(self.name):,} characters" if isinstance(self.name, str)
                     else repr(self.name)[:80])
            raise SceneError(f"a scene name is text of 1 to {MAX_NAME} characters, "
                             f"got {shown}")
        # stored as UTF-8 (SQLite, JSON, HDF5 attributes): an unpaired surrogate was a job
        # stored beside a 500, whose record broke the service's job list; a NUL, an HDF5
        # attribute it cannot hold
        if "\0" in self.name or _not_utf8(self.name):
            raise SceneError("a scene name is UTF-8 text without NUL characters (it holds an "
                             "unpaired surrogate or a NUL)")
        if self.pairs is not None:
            object.__setattr__(self, "pairs", _clean_pairs(self.pairs, self))

    # -- construction ------------------------------------------------------------------

    @classmethod
    def preset(cls, name: str, **overrides) -> Scene:
        if name not in PRESETS:
            raise SceneError(f"unknown scene preset {name!r}; choose one of {', '.join(PRESETS)}")
        return cls(**{**PRESETS[name], "name": name, **overrides})

    @classmethod
    def from_dict(cls, d: dict, base_dir: str = ".") -> Scene:
        """A scene from its JSON form (see the module docstring for the keys)."""
        if not isinstance(d, dict):
            raise SceneError("a scene description must be a JSON object")
        known = {"preset", "max_theta_i", "max_theta_o", "pairs", "lights", "views",
                 "pairs_file", "spread", "name"}
        unknown = set(d) - known
        if unknown:
            raise SceneError(f"unknown scene key(s) {sorted(unknown)}; expected {sorted(known)}")
        kw: dict = {}
        if "preset" in d:
            if not isinstance(d["preset"], str) or d["preset"] not in PRESETS:
                raise SceneError(
                    f"unknown scene preset {d['preset']!r}; choose one of {', '.join(PRESETS)}"
                )
            kw.update(PRESETS[d["preset"]], name=d["preset"])
        for k in ("max_theta_i", "max_theta_o", "spread", "name"):
            if k in d:
                kw[k] = d[k]
        parts = []
        if "pairs" in d:
            parts.append(_as_pairs(d["pairs"], "pairs"))
        if "lights" in d or "views" in d:
            if "lights" not in d or "views" not in d:
                raise SceneError("a scene needs both 'lights' and 'views', or neither")
            lights = _as_dirs(d["lights"], "lights")
            views = _as_dirs(d["views"], "views")
            _not_too_many(len(lights) * len(views),
                          f"{len(lights):,} lights with {len(views):,} views")
            parts.append(np.stack(np.broadcast_arrays(lights[:, None], views[None, :]),
                                  axis=2).reshape(-1, 2, 3))
        if "pairs_file" in d:
            if not isinstance(d["pairs_file"], str) or not d["pairs_file"]:
                raise SceneError("scene pairs_file: the path of a .npy or .csv file of "
                                 f"pairs, relative to the scene's file; got {d['pairs_file']!r}")
            parts.append(read_pairs(os.path.join(base_dir, d["pairs_file"])))
        if parts:
            _not_too_many(sum(map(len, parts)), "its pairs")
            kw["pairs"] = np.concatenate(parts)
        scene = cls(**kw)
        if len(parts) == 1 and "lights" in d:  # lights x views alone
            object.__setattr__(scene, "lights_views", (lights, views))
        return scene

    @classmethod
    def from_file(cls, path: str | os.PathLike) -> Scene:
        """A scene from a .json description or a .npy / .csv file of pairs."""
        path = os.fspath(path)
        ext = os.path.splitext(path)[1].lower()
        if ext not in (".json", ".npy", ".csv"):
            raise SceneError(f"{path}: a scene file is .json, .npy or .csv, not "
                             f"{ext or 'no suffix'}")
        if ext == ".json":
            _a_file(path)
            try:
                # a byte-order mark, as Windows editors write one, is read past (as a fit
                # JSON's is by export)
                with open(path, encoding="utf-8-sig") as f:
                    d = json.load(f)
            except json.JSONDecodeError as e:
                raise SceneError(f"{path}: not valid JSON ({e})") from None
            except RecursionError:
                raise SceneError(f"{path}: not a scene: JSON nested too deeply") from None
            except UnicodeDecodeError:
                raise SceneError(f"{path}: not UTF-8 text (a scene's JSON is)") from None
            if isinstance(d, dict) and "name" not in d and "preset" not in d:
                d["name"] = os.path.basename(path)
            return cls.from_dict(d, base_dir=os.path.dirname(path))
        return cls(pairs=read_pairs(path), name=os.path.basename(path))

    @classmethod
    def from_options(
        cls,
        scene: str | os.PathLike | dict | Scene | None = None,
        *,
        preset: str | None = None,
        max_theta: float | None = None,
        max_theta_i: float | None = None,
        max_theta_o: float | None = None,
    ) -> Scene | None:
        """The scene of CLI/API options (a file, a dict, a preset, angle limits), or
        ``None`` when none is given. Angle limits override those of the file/preset."""
        if isinstance(scene, Scene):
            base = scene
        elif isinstance(scene, dict):
            base = cls.from_dict(scene)
        elif scene is not None:
            base = cls.from_file(scene)
        elif preset is not None:
            base = cls.preset(preset)
        else:
            base = None
        if scene is not None and preset is not None:
            raise SceneError("give a scene file or a scene preset, not both")
        limits = {}
        if max_theta is not None:
            limits = {"max_theta_i": max_theta, "max_theta_o": max_theta}
        if max_theta_i is not None:
            limits["max_theta_i"] = max_theta_i
        if max_theta_o is not None:
            limits["max_theta_o"] = max_theta_o
        if not limits:
            return base
        if base is None:
            return cls(**limits, name="angle limits")
        return replace(base, **limits)

    # -- what a fit needs --------------------------------------------------------------

    def bin_weight(self) -> np.ndarray:
        """Weight per flat MERL bin (>= 0, 0 = unused, mean 1 over the used bins)."""
        return self._weight

    @functools.cached_property
    def _weight(self) -> np.ndarray:  # a scene is immutable: bin it once
        w = _angle_mask(self.max_theta_i, self.max_theta_o).astype(np.float64)
        if self.pairs is not None:
            w = w * _pair_weight(self.pairs, self.spread)
        used = w > 0
        if not used.any():
            raise SceneError(f"scene {self.name!r} uses no MERL bin above the horizon")
        w /= w[used].mean()
        w.setflags(write=False)
        return w

    @property
    def n_bins(self) -> int:
        return int(np.count_nonzero(self.bin_weight()))

    @property
    def solid_angle_fraction(self) -> float:
        """Share of the hemisphere-pair measure that the scene's bins cover."""
        return float(bin_grid().weight[self.bin_weight() > 0].sum())

    def describe(self) -> str:
        bits = []
        if self.max_theta_i < 90:
            bits.append(f"theta_i <= {self.max_theta_i:g} deg")
        if self.max_theta_o < 90:
            bits.append(f"theta_o <= {self.max_theta_o:g} deg")
        if self.pairs is not None:
            bits.append(f"{len(self.pairs):,} direction pairs (spread {self.spread:g} deg)")
        what = ", ".join(bits) or "whole hemisphere"
        return (f"{self.name}: {what}; {self.n_bins:,} bins, "
                f"{100 * self.solid_angle_fraction:.2g}% of the solid angle")

    def to_spec(self, *, pairs_listed: bool = False) -> dict:
        """The scene as :meth:`from_dict` reads it (the pairs listed, as kept; lights and
        views where it was given as every pairing of them): what a request stores, so
        that the same scene comes back from it."""
        spec = {"name": self.name, "max_theta_i": self.max_theta_i,
                "max_theta_o": self.max_theta_o, "spread": self.spread}
        if self.lights_views is not None and not pairs_listed:  # the same pairs, as given
            spec["lights"], spec["views"] = (np.asarray(a, np.float64).tolist()
                                             for a in self.lights_views)
        elif self.pairs is not None:
            spec["pairs"] = np.asarray(self.pairs, np.float64).tolist()
        return spec

    def key(self) -> str:
        """A short identity of what the scene weights (its name and a hash of
        :meth:`to_spec` with the pairs listed, however the scene was given: a batch
        file's keys from before lights and views were kept stay its keys): a batch
        resumes a fit only under the same scene."""
        import hashlib

        from brdffit import jsonout

        text = jsonout.dumps(self.to_spec(pairs_listed=True), sort_keys=True,
                             separators=(",", ":"))
        return f"{self.name}:{hashlib.sha256(text.encode()).hexdigest()[:16]}"

    def __eq__(self, other) -> bool:
        if not isinstance(other, Scene):
            return NotImplemented
        return self.key() == other.key()

    __hash__ = None  # mutable arrays inside: equal by value, not hashable

    def to_dict(self) -> dict:
        """Plain JSON summary (the pairs themselves are counted, not listed)."""
        return {
            "name": self.name,
            "max_theta_i": self.max_theta_i,
            "max_theta_o": self.max_theta_o,
            "pairs": None if self.pairs is None else len(self.pairs),
            "dropped_pairs": self.dropped_pairs,
            "spread": self.spread,
            "bins": self.n_bins,
            "solid_angle_fraction": self.solid_angle_fraction,
            "description": self.describe(),
        }


# -- reading pairs -----------------------------------------------------------------------


def read_pairs(path: str) -> np.ndarray:
    """(N, 2, 3) direction pairs from a .npy or .csv file (see the module docstring)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".npy", ".csv"):
        raise SceneError(f"{path}: direction pairs are a .npy or .csv file, not "
                         f"{ext or 'no suffix'}")
    _a_file(path)
    if ext == ".npy":
        try:
            # mapped first: its shape is refused before a huge array is read
            a = np.load(path, allow_pickle=False, mmap_mode="r")
            _not_too_many(a.shape[0] if a.ndim else 1, f"{path}'s pairs")
            if a.dtype.kind not in "iuf":  # a complex array's imaginary part was dropped
                raise ValueError(f"its values are {a.dtype}, not real numbers")
            a = np.array(a)
        except (ValueError, EOFError, OSError) as e:  # EOFError: an empty file
            raise SceneError(f"{path}: not a numeric .npy array "
                             f"({e or type(e).__name__})") from None
    else:
        try:
            a = _read_csv(path)
        except UnicodeDecodeError:
            raise SceneError(f"{path}: not UTF-8 text (a .csv of pairs is)") from None
    return _as_pairs(a, path)


def _not_utf8(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return False


def _not_too_many(n: int, what: str) -> None:
    if n > MAX_PAIRS:
        raise SceneError(
            f"scene with {n:,} direction pairs ({what}): at most {MAX_PAIRS:,}. A scene "
            "is binned onto the table's 1.46M bins, so a subset drawn at random (or every "
            "k-th pair) weights the fit alike")


def _a_file(path: str) -> None:
    if not os.path.exists(path):
        raise SceneError(f"{path}: no such scene file")
    if not os.path.isfile(path):
        raise SceneError(f"{path}: not a file (a directory?)")


def _read_csv(path: str) -> np.ndarray:
    rows, header_allowed = [], True
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            cells = [c.strip() for c in line.replace(";", ",").split(",")]
            if len(rows) == MAX_PAIRS:
                _not_too_many(MAX_PAIRS + 1, f"{path} has more lines")
            try:
                rows.append([float(c) for c in cells])
            except ValueError:
                if not header_allowed:
                    raise SceneError(f"{path}:{n}: not six numbers: {line!r}") from None
            header_allowed = False  # only the first content line may be a header
    if not rows:
        raise SceneError(f"{path}: no direction pairs")
    if len({len(r) for r in rows}) != 1:
        raise SceneError(f"{path}: every line needs the same six numbers")
    return np.asarray(rows)


def _no_truth_values(a, what: str) -> None:
    """Refuses true or false among a JSON list's numbers (numpy reads them as 1 and 0;
    ``max_theta_i: true`` is refused as no number too)."""
    if isinstance(a, list | tuple):
        try:
            flat = np.asarray(a, dtype=object).ravel()
        except ValueError:  # ragged: refused by its shape below
            return
        if any(type(x) is bool for x in flat):
            raise SceneError(f"scene {what}: numbers, not true or false")


def _as_dirs(a, what: str) -> np.ndarray:
    _no_truth_values(a, what)
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"scene {what}: not a list of 3-vectors") from None
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] == 0:
        raise SceneError(f"scene {what}: need a non-empty list of 3-vectors, got shape {a.shape}")
    return a


def _as_pairs(a, what: str) -> np.ndarray:
    _no_truth_values(a, what)
    try:
        a = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise SceneError(f"scene {what}: not numeric direction pairs") from None
    if a.ndim == 2 and a.shape[1] == 6:
        a = a.reshape(-1, 2, 3)
    if a.ndim != 3 or a.shape[1:] != (2, 3) or a.shape[0] == 0:
        raise SceneError(
            f"scene {what}: need N pairs as (N, 6) or (N, 2, 3) numbers, got shape {a.shape}"
        )
    return a


def _clean_pairs(pairs, scene: Scene) -> np.ndarray:
    """Unit pairs above the horizon; records how many were dropped."""
    a = _as_pairs(pairs, "pairs")
    _not_too_many(len(a), "its pairs")
    if not np.all(np.isfinite(a)):
        raise SceneError("scene pairs contain non-finite numbers")
    # each direction scaled by its largest component first: its length then cannot
    # overflow (a direction of 1e308s is as good a direction as any)
    largest = np.max(np.abs(a), axis=-1, keepdims=True)
    a = a / np.where(largest > 0, largest, 1.0)
    norm = np.linalg.norm(a, axis=-1, keepdims=True)
    ok = np.all(norm[..., 0] > 0, axis=1)
    a = a / np.where(norm > 0, norm, 1.0)
    ok &= np.all(a[..., 2] > 0, axis=1)
    object.__setattr__(scene, "dropped_pairs", scene.dropped_pairs + int(np.count_nonzero(~ok)))
    if not ok.any():
        raise SceneError(f"none of the {len(a)} scene pairs has both directions above the horizon")
    return a[ok]


# -- binning -----------------------------------------------------------------------------


def _angle_mask(max_theta_i: float, max_theta_o: float) -> np.ndarray:
    g = bin_grid()
    ci, co = math.cos(math.radians(max_theta_i)), math.cos(math.radians(max_theta_o))
    # >= with a hair of slack: a limit of 90 deg must keep bins with cos ~ 1e-4
    direct = (g.cos_i >= ci - 1e-12) & (g.cos_o >= co - 1e-12)
    swapped = (g.cos_o >= ci - 1e-12) & (g.cos_i >= co - 1e-12)
    return g.above_horizon & (direct | swapped)


def _cone_jitter(dirs: np.ndarray, k: int, spread_deg: float, rng) -> np.ndarray:
    """``k`` directions uniform in a cone of half-angle ``spread_deg`` around each of
    ``dirs`` (N, 3) -> (N, k, 3)."""
    n = dirs.shape[0]
    cos_max = math.cos(math.radians(spread_deg))
    z = 1.0 - rng.random((n, k)) * (1.0 - cos_max)
    phi = rng.random((n, k)) * 2 * math.pi
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    # an orthonormal frame around each direction
    helper = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t = np.cross(helper, dirs)
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    b = np.cross(dirs, t)
    return (local[..., 0:1] * t[:, None] + local[..., 1:2] * b[:, None]
            + local[..., 2:3] * dirs[:, None])


def _pair_weight(pairs: np.ndarray, spread: float) -> np.ndarray:
    g = bin_grid()
    n = len(pairs)
    k = 1 if spread == 0 else int(np.clip(_MAX_LOOKUPS // n, 1, 256))
    rng = np.random.default_rng(0)  # deterministic: the same scene, the same weights
    wi, wo = pairs[:, 0], pairs[:, 1]
    if k > 1:  # the pairs themselves, then their jittered copies: a pair's own bin counts
        wi = np.concatenate([wi, _cone_jitter(wi, k, spread, rng).reshape(-1, 3)])
        wo = np.concatenate([wo, _cone_jitter(wo, k, spread, rng).reshape(-1, 3)])
    keep = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    idx = flat_index(*half_diff_to_bins(*dirs_to_half_diff(wi[keep], wo[keep])))
    counts = np.bincount(idx, minlength=g.weight.size).astype(np.float64)
    # counts are the scene's density times the bin's measure: divide the measure out,
    # the fit multiplies it back in (loss weight = solid angle x scene = counts).
    return np.where(g.weight > 0, counts / np.where(g.weight > 0, g.weight, 1.0), 0.0)


# -- fitting in a scene --------------------------------------------------------------------


def as_scene(scene) -> Scene:
    """The scene a library caller names (``fit(..., scene=)``, ``select(..., scene=)``):
    a :class:`Scene`, its JSON form (a dict), a preset's name (:data:`PRESETS`) or a
    scene file's path. Raises :class:`SceneError` for anything else."""
    if isinstance(scene, str) and scene in PRESETS:
        return Scene.preset(scene)
    if (isinstance(scene, str) and not os.path.splitext(scene)[1]
            and not os.path.exists(scene)):  # no file, and named as no file is
        raise SceneError(f"unknown scene preset {scene!r}; choose one of "
                         f"{', '.join(PRESETS)} (or a scene file: .json, .npy, .csv)")
    if not isinstance(scene, Scene | dict | str | os.PathLike):
        raise SceneError("a scene is a brdffit.fitting.scene.Scene, its JSON form (a dict), "
                         f"a preset's name ({', '.join(PRESETS)}) or a scene file's path, "
                         f"got {type(scene).__name__}")
    return Scene.from_options(scene)



@runtime.in_float64
def full_table_error(table, model, params: dict) -> dict[str, float]:
    """Error metrics (``brdffit.fitting.loss``) of ``params`` on every usable bin of ``table``,
    solid-angle weighted, whatever scene the fit used."""
    from brdffit.fitting.problem import table_error

    return table_error(table, model, params)


#: What a scene fit's verdict of a sphere says of itself (``quality.of_the_whole_sphere``).
WHOLE_SPHERE_WORDS = ("judged on the whole sphere, every direction, where the fit weighted "
                      "the scene's alone")
