"""Measured samples in any layout (issue 39, first part): brdffit.io.measurements and
brdffit.io.readers. Every format reads to the same samples; every malformed file gets
one line naming the file and the first bad row; binning onto the MERL grid keeps a
table's own bins exactly and reports what it moved; a fit of a sample file recovers
the material that made it. (The shells: tests/test_measurement_shells.py.)"""

from __future__ import annotations

import json
import re

import h5py
import numpy as np
import pytest

from brdffit.errors import MerlFormatError
from brdffit.io import merl
from brdffit.io.angles import bin_centres, half_diff_to_dirs
from brdffit.io.measurements import Measurements, MeasurementsError
from brdffit.io.readers import declared_samples, read_measured, read_table

pytestmark = pytest.mark.unit

COLUMNS = "theta_i,phi_i,theta_o,phi_o"


def _samples(n=500, seed=0):
    """Gonioreflectometer-like samples: light on rings, view anywhere above."""
    rng = np.random.default_rng(seed)
    theta_i = rng.choice(np.radians([10.0, 30.0, 50.0, 70.0]), n)
    phi_i = np.zeros(n)
    theta_o = np.arccos(rng.uniform(0.05, 1.0, n))
    phi_o = rng.uniform(0.0, 2 * np.pi, n)
    rgb = rng.uniform(0.05, 2.0, (n, 3))
    return theta_i, phi_i, theta_o, phi_o, rgb


def _write_all(tmp_path, s):
    theta_i, phi_i, theta_o, phi_o, rgb = s
    deg = [np.degrees(a) for a in (theta_i, phi_i, theta_o, phi_o)]
    rows = np.column_stack([*deg, rgb])
    csv = tmp_path / "s.csv"
    csv.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                   + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    tsv = tmp_path / "s.tsv"
    tsv.write_text("# angles: degrees\n# a comment line\ntheta_i\tphi_i\ttheta_r\tphi_r\tr\tg\tb\n"
                   + "\n".join("\t".join(repr(float(x)) for x in r) for r in rows) + "\n")
    astm = tmp_path / "s.astm"
    rad = np.column_stack([theta_i, phi_i, theta_o, phi_o, rgb])
    astm.write_text(f"SOURCE test\nNUM_POINTS {len(rad)}\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n"
                    + "\n".join(",".join(repr(float(x)) for x in r) for r in rad) + "\n")
    h5 = tmp_path / "s.h5"
    with h5py.File(h5, "w") as f:
        for name, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), deg, strict=True):
            f[name] = a
            f[name].attrs["units"] = "degrees"
        f["rgb"] = rgb
    return {"csv": csv, "tsv": tsv, "astm": astm, "hdf5": h5}


def test_every_layout_reads_to_the_same_samples(tmp_path):
    s = _samples()
    files = _write_all(tmp_path, s)
    reference = Measurements.from_angles(*s[:4], s[4])
    for kind, path in files.items():
        got = read_measured(path)
        assert isinstance(got, Measurements), kind
        assert got.n == 500 and got.source == str(path)
        np.testing.assert_allclose(got.wi, reference.wi, atol=1e-12, err_msg=kind)
        np.testing.assert_allclose(got.wo, reference.wo, atol=1e-12, err_msg=kind)
        np.testing.assert_allclose(got.rgb, reference.rgb, rtol=1e-15, err_msg=kind)
    # by content where the suffix says nothing
    unnamed = tmp_path / "samples"
    unnamed.write_bytes(files["astm"].read_bytes())
    assert read_measured(unnamed).provenance["format"] == "astm"
    h5 = tmp_path / "samples.dat"
    h5.write_bytes(files["hdf5"].read_bytes())
    assert read_measured(h5).provenance["format"] == "hdf5"


def test_a_pipe_is_read_as_the_file_it_carries(tmp_path):
    """brdffit fit <(zcat t.csv.gz): a stream has no size and is read once (it read as
    an empty file); copied whole, it reads as the layout it carries, named as given."""
    import os
    import threading

    s = _samples(50)
    files = _write_all(tmp_path, s)
    for kind in ("csv", "hdf5"):
        fifo = tmp_path / f"stream-{kind}"
        os.mkfifo(fifo)
        data = files[kind].read_bytes()
        writer = threading.Thread(target=lambda f=fifo, d=data: f.write_bytes(d))
        writer.start()
        got = read_measured(fifo)
        writer.join(10)
        assert got.n == 50 and got.source == str(fifo), kind
        np.testing.assert_allclose(got.rgb, s[4], rtol=1e-15, err_msg=kind)


def test_one_channel_and_sigma(tmp_path):
    p = tmp_path / "grey.csv"
    p.write_text("theta_i_rad,phi_i_rad,theta_o_rad,phi_o_rad,value,sigma\n"
                 "0.1,0,0.2,3.0,0.5,0.01\n0.3,0,0.4,1.0,0.25,0.02\n")
    m = read_measured(p)
    np.testing.assert_array_equal(m.rgb, [[0.5] * 3, [0.25] * 3])
    np.testing.assert_array_equal(m.sigma, [[0.01] * 3, [0.02] * 3])
    assert m.provenance["channels"] == 1


@pytest.mark.parametrize("name, text, says", [
    ("a.csv", "", "empty"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n", "no data"),
    ("a.csv", "theta_i,phi_i,theta_o,phi_o,r,g,b\n1,2,3,4,1,1,1\n", "has no unit"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,r,g,b\n1,2,3,1,1,1\n", "no column for phi_o"),
    ("a.csv", "theta_i_deg,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n",
     "appears twice"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g\n1,2,3,4,1,1\n",
     "only r, g of r, g, b"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,1,1\n"
              "10,0,95,0,1,1,1\n",
     "theta_o_deg is below the horizon (more than 90 degrees from the normal) in 1 row "
     "(first: row 3)"),
    # an angle is named as the file names it
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n0.1,0,1.9,0,1,1,1\n",
     "theta_s (read as theta_o) is below the horizon"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n-10,0,20,0,1,1,1\n",
     "theta_i_deg is negative"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n-0.02,0,20,0,1,1,1\n",
     "theta_i_deg is negative"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,nan,0,1,1,1\n",
     "theta_o_deg is not finite in 1 row (first: row 2)"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,inf,1\n",
     "a value is not finite"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,-1,1\n",
     "a value is negative"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,1\n",
     "row 2 has 6 values, the header names 7 columns"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,x,1,1,1\n",
     "row 2 is not all numbers"),
    ("a.astm", "NUM_POINTS 2\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n0.1,0,0.2,0,1,1,1\n",
     "NUM_POINTS says 2 rows, the file has 1"),
    ("a.astm", "NUM_POINTS 1\n0.1,0,0.2,0,1,1,1\n", "no VARS line"),
    # a row of NaN first is a data row (it was read as a header key and dropped)
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\nnan,0,0.2,0,1,1,1\n"
               "0.1,0,0.2,0,1,1,1\n", "theta_i is not finite in 1 row (first: row 2)"),
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\nInf,0,0.2,0,1,1,1\n",
     "theta_i is not finite"),
    ("a.csv", "# angles: furlongs\ntheta_i,phi_i,theta_o,phi_o,r,g,b\n1,2,3,4,1,1,1\n",
     "unknown angle unit 'furlongs'"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,1e300,20,0,1,1,1\n",
     "phi_i_deg is beyond +-720 degrees in 1 row (first: row 2)"),
    # the last unit line won, and a file in degrees was read in radians
    ("a.csv", "# angles: degrees\n# angles: radians\ntheta_i,phi_i,theta_o,phi_o,r,g,b\n"
              "1,2,3,4,1,1,1\n", "two angle units: 'degrees' (line 1) and 'radians' (line 2)"),
    # Python's float() reads 1_0 as 10
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1_0,1,1\n",
     "row 2 is not all numbers"),
    # ... and an Arabic-Indic one as 1
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,\u0661,1,1\n",
     "row 2 is not all numbers"),
    # rows split by another delimiter than the header's: said (it read "1 values" alone)
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10;0;20;0;1;1;1\n",
     "row 2 has 1 values, the header names 7 columns (this row is split by semicolons, the "
     "header by commas: use one delimiter for both)"),
    # a comma-decimal locale's numbers split by commas too: the likely cause said
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,0,25,0,5,1\n",
     "row 2 has 9 values, the header names 7 columns (decimal commas in a comma-separated "
     "file? Separate the cells by ';' or tabs"),
    # value and sigma columns that would be guessed at or dropped are refused
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,x,y,z\n10,0,20,0,1,1,1\n",
     "columns x, y, z: CIE XYZ"),
    # named as CIE's beside a Y: the Y was read alone, as grey (stop 74's fuzzing)
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,CIE_X,CIE_Y,CIE_Z,Y\n"
              "10,0,20,0,1,1,1,1\n", "columns CIE_X, CIE_Y, CIE_Z, Y: CIE XYZ"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,value\n10,0,20,0,1,1,1\n",
     "value columns of two kinds: r, g (RGB) and value (one channel)"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma_r,sigma_g\n"
              "10,0,20,0,1,1,1,0.1,0.1\n",
     "sigma columns sigma_r, sigma_g: expected sigma, or sigma_r, sigma_g and sigma_b"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma,sigma_r,sigma_g,sigma_b\n"
              "10,0,20,0,1,1,1,0.1,0.1,0.1,0.1\n",
     "sigma columns sigma, sigma_r, sigma_g, sigma_b"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,value,sigma_r,sigma_g,sigma_b\n"
              "10,0,20,0,1,0.1,0.1,0.1\n",
     "expected one column sigma"),
    # in-plane data without azimuths: which side a signed angle is on is asked for
    ("a.csv", "theta_i_deg,theta_o_deg,r,g,b\n10,-20,1,1,1\n",
     "no column for phi_i, phi_o (the header has theta_i_deg, theta_o_deg, r, g, b); "
     "in-plane samples still need them: phi_i 0 and phi_o 180 on the side opposite"),
    # a reflectance in percent is named as such, not as a file without values
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r [%],g [%],b [%]\n"
              "10,0,20,0,1,1,1\n",
     "'r [%]', 'g [%]', 'b [%]': a unit that is not 1/sr"),
    # two statements of one column's unit that disagree: which one holds is a guess
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\nrad,rad,rad,rad,,,\n"
              "0.1,0,0.2,0,1,1,1\n",
     "column 'theta_i_deg': two units (its name degrees, the units row radians)"),
    ("a.csv", "# angles: radians\ntheta_i,phi_i,theta_o,phi_o,r,g,b\ndeg,deg,deg,deg,,,\n"
              "10,0,20,0,1,1,1\n",
     "column 'theta_i': two units (the units row degrees, the '# angles:' line radians)"),
    ("a.csv", "# angles: radians\ntheta_i_deg,phi_i,theta_o,phi_o,r,g,b\n10,0,20,0,1,1,1\n",
     "column 'theta_i_deg': two units (its name degrees, the '# angles:' line radians)"),
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\nNUM_POINTS 7\nNUM_POINTS 1\n"
               "0.1,0,0.2,0,1,1,1\n", "NUM_POINTS is given twice: '7' and '1' (line 3)"),
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\nVARS R,G,B,theta_i,phi_i,theta_s,phi_s\n"
               "0.1,0,0.2,0,1,1,1\n", "VARS is given twice"),
    # np.savetxt(header=...) writes the header as a comment
    ("a.csv", "# theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,1,1\n",
     "no header: the first row is numbers; line 1 looks like one written as a comment"),
    ("a.csv", "10,0,20,0,1,1,1\n", "no header: the first row is numbers: name the columns"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma\n"
              "10,0,20,0,1,1,1,1e200\n", "sigma is above 1e+12 1/sr in 1 row (first: row 2)"),
    # a sigma of 0 weighed its value as exact, through a floor, silently
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma\n"
              "10,0,20,0,1,1,1,0.1\n10,0,30,0,1,1,1,0\n10,0,40,0,1,1,1,0\n",
     "sigma is 0 in 2 rows (first: row 3): a standard deviation is > 0"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma_r,sigma_g,sigma_b\n"
              "10,0,20,0,1,1,1,0.1,0,0.1\n",
     "sigma_g is 0 in 1 row (first: row 2): a standard deviation is > 0 (a sigma of 0 would "
     "weigh its value as exact); drop the sigma columns"),
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,sigma\n"
              "10,0,20,0,1,1,1,-0.1\n10,0,20,0,1,1,1,nan\n",
     "sigma is negative or not finite in 2 rows (first: row 2)"),
])
def test_a_malformed_file_gets_one_line_naming_it(tmp_path, name, text, says):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(MeasurementsError) as e:
        read_measured(path)
    message = str(e.value)
    assert message.startswith(f"{path}: ") and says in message, message
    assert "\n" not in message
    assert isinstance(e.value, MerlFormatError)  # every shell reports it as a bad table


def test_hdf5_needs_its_units(tmp_path):
    p = tmp_path / "s.h5"
    with h5py.File(p, "w") as f:
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            f[name] = np.zeros(3)
        f["rgb"] = np.ones((3, 3))
    with pytest.raises(MeasurementsError, match="has no 'units' attribute"):
        read_measured(p)
    # the file's unit and a dataset's own that disagree: refused, as a CSV's are (the
    # dataset's won, unsaid); that agree, in other words: read
    with h5py.File(p, "a") as f:
        f.attrs["units"] = "degrees"
        f["theta_i"].attrs["units"] = "radians"
    with pytest.raises(MeasurementsError, match="dataset theta_i: two units .its own 'units' "
                                                "'radians', the file's 'degrees'"):
        read_measured(p)
    with h5py.File(p, "a") as f:
        f["theta_i"].attrs["units"] = "deg"
    assert read_measured(p).n == 3
    with pytest.raises(MerlFormatError, match="No such file"):
        read_measured(tmp_path / "missing.csv")
    binary = tmp_path / "text.binary"
    binary.write_text("theta_i_deg\n")
    with pytest.raises(MerlFormatError, match="text"):
        read_measured(binary)  # a .binary is read as MERL, which says what is wrong


def test_hdf5_angles_may_have_the_names_a_csv_column_has(tmp_path):
    """``theta_in``, ``Theta_S``, ... as in a CSV header (they were "no dataset
    theta_i"); two datasets for one angle are refused."""
    s = _samples(30)
    want = read_measured(_write_all(tmp_path, s)["hdf5"])
    other = tmp_path / "other.h5"
    with h5py.File(tmp_path / "s.h5", "r") as src, h5py.File(other, "w") as f:
        for old, new in (("theta_i", "theta_in"), ("phi_i", "Phi_In"), ("theta_o", "Theta_S"),
                         ("phi_o", "phi_s"), ("rgb", "rgb")):
            f[new] = src[old][()]
            f[new].attrs.update(src[old].attrs)
    got = read_measured(other)
    np.testing.assert_array_equal(got.wi, want.wi)
    np.testing.assert_array_equal(got.wo, want.wo)
    with h5py.File(other, "a") as f:
        f["theta_o"] = f["Theta_S"][()]
    with pytest.raises(MeasurementsError, match="two datasets give theta_o"):
        read_measured(other)


def _matlab_73(path, s, names=("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg"),
               user_block=True):
    """A .mat file as MATLAB's ``save -v7.3`` writes one: HDF5 after a 512-byte header
    of its own, each variable column-major (an n x 3 matrix stored (3, n), a column
    vector (1, n)), tagged ``MATLAB_class``, and no other attribute."""
    theta_i, phi_i, theta_o, phi_o, rgb = s
    columns = [np.degrees(a) for a in (theta_i, phi_i, theta_o, phi_o)]
    with h5py.File(path, "w", **({"userblock_size": 512} if user_block else {})) as f:
        for name, a in (*zip(names, columns, strict=True), ("rgb", rgb)):
            f[name] = np.asarray(a).reshape(len(theta_i), -1).T
            f[name].attrs["MATLAB_class"] = np.bytes_("double")
    if user_block:
        with open(path, "r+b") as f:
            f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sun Dec  6 "
                    b"00:00:00 2026 HDF5 schema 1.00 .".ljust(116) + bytes(8) + b"\x00\x02IM")
    return path


def test_a_matlab_v73_file_reads_as_matlab_holds_it(tmp_path):
    """``save('s.mat', ..., '-v7.3')`` writes HDF5 behind a 512-byte header, with
    MATLAB's column-major matrices and no attributes: read by content whatever its
    name, transposed back, the angles' units from their names (it was read as a MERL
    table, "not a text file"). A (3, n) dataset of another writer is refused with what
    to do, and a MATLAB matrix of the wrong shape is named as MATLAB names it."""
    s = _samples(40)
    want = read_measured(_write_all(tmp_path, s)["csv"])
    for path in (_matlab_73(tmp_path / "s.mat", s), _matlab_73(tmp_path / "s_mat", s),
                 _matlab_73(tmp_path / "s.h5", s, user_block=False)):
        got = read_measured(path)
        np.testing.assert_allclose(got.rgb, want.rgb, rtol=1e-12)
        np.testing.assert_allclose(got.wi, want.wi, atol=1e-12)
        np.testing.assert_allclose(got.wo, want.wo, atol=1e-12)
        assert declared_samples(path) == 40  # what the service weighs an upload by
    bare = _matlab_73(tmp_path / "bare.mat", s, names=("theta_i", "phi_i", "theta_o", "phi_o"))
    with pytest.raises(MeasurementsError, match="name it theta_i_deg or theta_i_rad .MATLAB's "
                                                "save writes no attributes"):
        read_measured(bare)
    with h5py.File(tmp_path / "s.h5", "a") as f:
        f["theta_i_deg"].attrs["units"] = "radians"
    with pytest.raises(MeasurementsError, match="theta_i_deg: two units .its name's 'deg', "
                                                "its 'units' 'radians'"):
        read_measured(tmp_path / "s.h5")
    other = tmp_path / "colmajor.h5"
    with h5py.File(other, "w") as f:
        for name, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), s[:4], strict=True):
            f[name] = a[None, :]  # a row: one number per sample all the same
        f.attrs["units"] = "radians"
        f["rgb"] = s[4].T
    with pytest.raises(MeasurementsError, match=r"rgb has shape \(3, 40\), not \(n, 3\); "
                                                r"\(3, n\) is how a column-major writer"):
        read_measured(other)
    wrong_way = _matlab_73(tmp_path / "wrong_way.mat", (*s[:4], np.zeros((3, 40))))
    with h5py.File(wrong_way, "a") as f:  # a 3 x 40 matrix in MATLAB: stored (40, 3)
        del f["rgb"]
        f["rgb"] = s[4]
        f["rgb"].attrs["MATLAB_class"] = np.bytes_("double")
    # it read "dataset rgb has shape (40, 3), not (n, 3)": its HDF5 storage's shape
    with pytest.raises(MeasurementsError, match=r"MATLAB variable rgb is 3 x 40, not n x 3: "
                                                r"save its transpose \(rgb'\)"):
        read_measured(wrong_way)
    # text is stored as its uint16 codes (they were read as numbers), a sparse matrix as
    # a group (said to be a struct or cell)
    for name, store, said in (
            ("theta_i_deg", lambda f: f.create_dataset("theta_i_deg", data=np.frombuffer(
                b"3\x000\x00", "<u2")[None, :]), "variable theta_i_deg holds text"),
            ("rgb", lambda f: f.create_group("rgb").attrs.update({"MATLAB_sparse": 40}),
             r"rgb is a sparse matrix: save full\(rgb\)")):
        with h5py.File(wrong_way, "a") as f:
            del f[name]
            store(f)
            f[name].attrs["MATLAB_class"] = np.bytes_("char" if name != "rgb" else "double")
        with pytest.raises(MeasurementsError, match=said):
            read_measured(wrong_way)
        _matlab_73(wrong_way, s)


def _matlab_v5(path, s, *, compressed=False, **more):
    """A .mat file as MATLAB's ``save`` writes one by default (version 5; ``-v7`` is
    compressed), written by scipy.io.savemat: the angles in degrees as column vectors,
    ``rgb`` n x 3, and ``more`` variables."""
    from scipy import io

    theta_i, phi_i, theta_o, phi_o, rgb = s
    names = ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")
    io.savemat(path, {**{k: np.degrees(a)[:, None] for k, a in
                         zip(names, (theta_i, phi_i, theta_o, phi_o), strict=True)},
                      "rgb": rgb, **more}, do_compression=compressed)
    return path


def test_a_matlab_v5_file_reads_as_its_variables_saved_v73_do(tmp_path):
    """``save``'s default (version 5, and -v7 compressed): read through scipy.io as
    the same variables of a -v7.3 file are (it was refused), whatever its name, with
    the same figures and MATLAB's words: a variable, 3 x 40. What it declares is
    weighed before a number is read."""
    s = _samples(40)
    want = read_measured(_matlab_73(tmp_path / "s73.mat", s))
    plain = _matlab_v5(tmp_path / "s.mat", s, note="gonio run 12")  # text: a note, not read
    paths = [plain, _matlab_v5(tmp_path / "z.mat", s, compressed=True)]
    for name in ("s_mat", "s.binary", "s.csv"):  # by content, unnamed or misnamed
        paths.append(tmp_path / name)
        paths[-1].write_bytes(plain.read_bytes())
    for path in paths:
        got = read_measured(path)
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(got.wi, want.wi)
        np.testing.assert_array_equal(got.wo, want.wo)
        assert got.provenance["format"] == "mat"
        assert declared_samples(path) == 40  # what the service weighs an upload by
    theta_i, phi_i, theta_o, phi_o, rgb = s
    for variables, said in (
            ({"rgb": rgb.T}, r"MATLAB variable rgb is 3 x 40, not n x 3: save its transpose "
                             r"\(rgb'\)"),
            ({"m": {"theta_i_deg": theta_i}}, r"m is a MATLAB struct: save its fields as "
                                              r"variables, save\('file.mat', '-struct', 'm'\)"),
            ({"RGB": rgb}, "variables rgb and RGB: keep one|two variables give rgb"),
            ({"sigma": np.array([[1, 2]], dtype=object)}, "sigma is a struct or cell, not a "
                                                            "matrix")):
        bad = tmp_path / "bad.mat"
        from scipy import io

        io.savemat(bad, {k: v for k, v in io.loadmat(plain).items()
                         if not k.startswith("__") and k not in ("rgb", "note")}
                   | ({} if "rgb" in variables or "m" in variables else {"rgb": rgb})
                   | variables)
        if "m" in variables:  # the angles inside a struct, none outside
            io.savemat(bad, variables)
        with pytest.raises(MeasurementsError, match=said):
            read_measured(bad)
    data = plain.read_bytes()
    for cut in (100, len(data) - 1000):  # in its last variable, or before the others
        (tmp_path / "cut.mat").write_bytes(data[:len(data) - cut])
        with pytest.raises(MeasurementsError, match="a MATLAB .mat file cut short: its last "
                                                    "variable runs past the end of the file"):
            read_measured(tmp_path / "cut.mat")
    (tmp_path / "other.mat").write_bytes(b"theta_i,phi_i\n")
    with pytest.raises(MeasurementsError, match="not a MATLAB .mat file of version 5, 7 or 7.3"):
        read_measured(tmp_path / "other.mat")
    # dimensions declared in a variable's header, far more than the file holds: refused
    # from the headers alone (scipy would read, or allocate, them all)
    rows = np.array([5, 8, 40, 1], "<i4").tobytes()  # miINT32, 8 bytes: 40 x 1
    assert data.count(rows) == 4
    for declared, said in ((3_000_000, "its variables declare 3,000,000 samples"),
                           (200_000_000, "variable theta_i_deg holds 200,000,000 numbers: "
                                         "more than a sample list read here")):
        huge = tmp_path / f"huge{declared}.mat"
        huge.write_bytes(data.replace(rows, np.array([5, 8, declared, 1], "<i4").tobytes(), 1))
        with pytest.raises(MeasurementsError, match=said):
            read_measured(huge)


@pytest.mark.system  # a second process holds the file open
def test_an_hdf5_file_h5py_cannot_open_says_why(tmp_path):
    """A truncated HDF5 file, and one another program holds open for writing, read as
    "an HDF5 file, not HDF5 (by its first bytes)": its signature was found, the rest
    was not read. Each now says what happened and what to do."""
    import subprocess
    import sys

    h5 = _write_all(tmp_path, _samples(2000))["hdf5"]
    cut = tmp_path / "cut.h5"
    cut.write_bytes(h5.read_bytes()[:3000])
    with pytest.raises(MeasurementsError, match=r"cut.h5: a truncated HDF5 file: 3,000 bytes "
                                                r"of the [\d,]+ it says it holds .* copy or "
                                                "write it again"):
        read_measured(cut)
    writer = subprocess.Popen([sys.executable, "-c", "import h5py, sys; f = h5py.File(sys.argv[1], "
                               "'a'); print('open', flush=True); sys.stdin.read()", str(h5)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert writer.stdout.readline().strip() == "open"
        with pytest.raises(MeasurementsError, match="another program holds open for writing "
                                                    ".*HDF5_USE_FILE_LOCKING=FALSE"):
            read_measured(h5)
    finally:
        writer.communicate("")
    assert read_measured(h5).n == 2000  # closed, it reads


def test_a_mat_file_reads_only_what_a_sample_list_holds(tmp_path, monkeypatch):
    """What the fuzzing of version-5 files found (stop 74): variables no fit reads are
    never read (a 23 KB file of empty sparse matrices took 4.9 GB, densified); a name or
    size that no HDF5 file holds is one line, not h5py's traceback or message; CIE XYZ,
    a long layout's channel beside wide values and an uncertainty by another name are
    refused as in a CSV; a MATLAB row vector of sigma is read as its angles are, an empty
    one as none; text, complex and logical values are named so."""
    import scipy.sparse
    from scipy import io

    from brdffit.io import matlab

    loaded = matlab._loaded
    s = _samples(40)
    plain = _matlab_v5(tmp_path / "s.mat", s)
    arrays = {k: v for k, v in io.loadmat(plain).items() if not k.startswith("__")}
    n = 40
    io.savemat(tmp_path / "junk.mat", {**arrays, **{f"junk{k}": scipy.sparse.csc_matrix(
        (10**8, 1)) for k in range(3)}})
    read_names = []
    monkeypatch.setattr(matlab, "_loaded", lambda path, source, names: read_names.extend(
        names) or loaded(path, source, names))
    assert read_measured(tmp_path / "junk.mat").n == n
    assert sorted(read_names) == sorted(arrays)  # the junk was never read
    monkeypatch.undo()
    grey = arrays["rgb"][:, 1]
    for variables, said in (
            ({"rgb": None, "X": grey, "Y": grey, "Z": grey},
             "variables X, Y, Z: CIE XYZ\\? A fit reads linear RGB"),
            # a long layout's channel beside wide values (read where its value is one
            # variable: test_a_long_layout_of_named_arrays_is_pivoted_as_a_csvs_is)
            ({"channel": np.ones(n)}, "variable 'channel' says which channel or wavelength "
                                      "each row holds .one row per direction and channel, a "
                                      "long layout.: each row's value is then one variable"),
            ({"wavelengths": np.full(n, 550.0)}, "variable 'wavelengths' says which"),
            ({"rgb_stderr": np.ones((n, 3))}, "variable 'rgb_stderr' looks like each "
                                              "value's uncertainty"),
            ({"variance": np.ones((n, 3))}, "variable 'variance' looks like"),
            ({"theta_i_deg": "30 40 50"}, "variable theta_i_deg holds text, not numbers"),
            ({"rgb": arrays["rgb"] + 0j}, "variable rgb holds complex numbers"),
            ({"rgb": arrays["rgb"] > 0}, "variable rgb holds booleans .a mask\\?.")):
        io.savemat(tmp_path / "bad.mat", {k: v for k, v in {**arrays, **variables}.items()
                                          if v is not None})
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / "bad.mat")
    # sigma as MATLAB's row vector (numpy's 1-d arrays are saved so): read, as angles are
    io.savemat(tmp_path / "row.mat", {**arrays, "sigma": np.full(n, 0.01)})
    np.testing.assert_array_equal(read_measured(tmp_path / "row.mat").sigma, np.full((n, 3),
                                                                                      0.01))
    # sigma = [], MATLAB's empty matrix: no sigma (it was refused as of shape (0, 0))
    io.savemat(tmp_path / "empty.mat", {**arrays, "sigma": np.zeros((0, 0))})
    assert read_measured(tmp_path / "empty.mat").sigma is None
    # hand-made headers: a name HDF5 cannot hold, a name twice, a negative size
    io.savemat(tmp_path / "named.mat", {**arrays, "zzzz": np.ones((2, 2)), "rgc": np.ones(2)})
    data = (tmp_path / "named.mat").read_bytes()
    dims = np.array([5, 8, 40, 3], "<i4").tobytes()  # rgb's: miINT32, 8 bytes, 40 x 3
    for changed, said in ((data.replace(b"zzzz", b"rgb/"), "a variable named 'rgb/'"),
                          (data.replace(b"rgc", b"rgb"), "variable rgb appears twice"),
                          (data.replace(dims, np.array([5, 8, -40, 3], "<i4").tobytes()),
                           r"variable rgb declares dimensions \[-40, 3\]")):
        (tmp_path / "bad.mat").write_bytes(changed)
        with pytest.raises(MeasurementsError, match="not a readable MATLAB .mat file .*" + said):
            read_measured(tmp_path / "bad.mat")
    io.savemat(tmp_path / "many.mat", {**arrays, **{f"v{k}": np.zeros((1, 1))
                                                    for k in range(1001)}})
    with pytest.raises(MeasurementsError, match="1,006 variables: more than a sample list "
                                                "holds"):
        read_measured(tmp_path / "many.mat")


def test_a_numpy_npz_archive_reads_as_hdf5_datasets_of_its_names(tmp_path):
    """``np.savez(..., theta_i_deg=..., rgb=...)``, compressed or not: read as an HDF5
    file of the same datasets is, whatever its name, with the same figures, in numpy's
    words (an array). Pickled objects are refused, never unpickled; what it declares is
    weighed before a number is read; a lone .npy says to name its arrays."""
    s = _samples(40)
    want = read_measured(_write_all(tmp_path, s)["hdf5"])
    theta_i, phi_i, theta_o, phi_o, rgb = s
    arrays = {"theta_i_rad": theta_i, "phi_i_rad": phi_i, "theta_o_rad": theta_o,
              "phi_o_rad": phi_o, "rgb": rgb}
    np.savez(tmp_path / "s.npz", **arrays, note=np.array("gonio run 12"))
    np.savez_compressed(tmp_path / "z.npz", **arrays)
    (tmp_path / "s.csv").write_bytes((tmp_path / "s.npz").read_bytes())  # misnamed
    for name in ("s.npz", "z.npz", "s.csv"):
        got = read_measured(tmp_path / name)
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(got.wi, want.wi)
        assert got.provenance["format"] == "npz"
        assert declared_samples(tmp_path / name) == 40
    for changed, said in (
            ({"rgb": np.array([{}] * 40, dtype=object)}, "array rgb holds Python objects "
                                                          r"\(pickled\), which are not read"),
            ({"rgb": rgb.T}, r"array rgb has shape \(3, 40\), not \(n, 3\)"),
            ({"theta_i": theta_i, "theta_i_rad": None},
             r"array theta_i has no unit: name it theta_i_deg or theta_i_rad \(an .npz "
             r"archive holds no attributes\)"),
            ({"rgb": None, "r": rgb[:, 0]}, "arrays r: only 1 of r, g, b")):
        bad = {k: v for k, v in {**arrays, **changed}.items() if v is not None}
        np.savez(tmp_path / "bad.npz", **bad)
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / "bad.npz")
    data = (tmp_path / "s.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    with pytest.raises(MeasurementsError, match="not a NumPy .npz archive|not a readable .npz"):
        read_measured(tmp_path / "cut.npz")
    np.savez(tmp_path / "empty.npz")  # an archive, of no arrays: not "not an .npz"
    with pytest.raises(MeasurementsError, match="an empty .npz archive: it holds no arrays"):
        read_measured(tmp_path / "empty.npz")
    np.save(tmp_path / "one.npy", rgb)
    with pytest.raises(MerlFormatError, match="a numpy .npy array .one array, unnamed: np.savez "
                                              "names them."):
        read_measured(tmp_path / "one.npy")
    # a shape declared in an array's header, far beyond what the file holds
    import io
    import zipfile

    with zipfile.ZipFile(tmp_path / "huge.npz", "w") as z:
        for name, a in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array_header_1_0(member, {
                "descr": "<f8", "fortran_order": False,
                "shape": (3_000_000,) if name == "theta_i_rad" else a.shape})
            z.writestr(f"{name}.npy", member.getvalue() + np.ascontiguousarray(a).tobytes())
    with pytest.raises(MeasurementsError, match="declare 3,000,000 samples"):
        read_measured(tmp_path / "huge.npz")


def test_hdf5_values_may_have_the_names_a_csv_column_has(tmp_path):
    """``RGB``, ``BRDF``, ``Value``: the names a CSV's value columns may have, in any
    case (a MATLAB variable ``BRDF`` was "no values"); a ``brdf`` of (n, 3) is RGB; two
    datasets of one kind are refused."""
    s = _samples(30)
    want = read_measured(_write_all(tmp_path, s)["hdf5"])
    for name, data, rgb in (("RGB", s[4], s[4]), ("BRDF", s[4], s[4]),
                            ("Value", s[4][:, 1], np.repeat(s[4][:, 1:2], 3, 1)),
                            ("y", s[4][:, 2:3], np.repeat(s[4][:, 2:3], 3, 1))):
        other = tmp_path / f"{name}.h5"
        with h5py.File(tmp_path / "s.h5", "r") as src, h5py.File(other, "w") as f:
            for a in ("theta_i", "phi_i", "theta_o", "phi_o"):
                f[a] = src[a][()]
                f[a].attrs.update(src[a].attrs)
            f[name] = data
        got = read_measured(other)
        np.testing.assert_array_equal(got.rgb, rgb)
        np.testing.assert_array_equal(got.wo, want.wo)
        assert declared_samples(other) == 30
    with h5py.File(other, "a") as f:
        f["brdf"] = s[4][:, 0]
    with pytest.raises(MeasurementsError, match="two datasets give value .'brdf' and 'y'.: "
                                                "keep one"):
        read_measured(other)
    # r, g and b as datasets of their own (MATLAB variables R, G, B), as a CSV's columns
    channels = tmp_path / "channels.h5"
    with h5py.File(tmp_path / "s.h5", "r") as src, h5py.File(channels, "w") as f:
        for a in ("theta_i", "phi_i", "theta_o", "phi_o"):
            f[a] = src[a][()]
            f[a].attrs.update(src[a].attrs)
        for k, name in enumerate(("R", "Green", "b")):
            f[name] = s[4][:, k]
    np.testing.assert_array_equal(read_measured(channels).rgb, want.rgb)
    with h5py.File(channels, "a") as f:
        del f["b"]
    with pytest.raises(MeasurementsError, match="datasets R, Green: only 2 of r, g, b"):
        read_measured(channels)
    with h5py.File(channels, "a") as f:
        f["b"], f["rgb"] = s[4][:, 2], s[4]
    with pytest.raises(MeasurementsError, match="datasets rgb and R, Green, b: values of more "
                                                "than one kind"):
        read_measured(channels)


def _h5(path, n=4, **datasets):
    with h5py.File(path, "w") as f:
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            f[name] = datasets.pop(name, np.linspace(5.0, 40.0, n))
            f[name].attrs["units"] = "degrees"
        for name, a in datasets.items():
            if a is None:
                f.create_group(name)
            else:
                f[name] = a
    return path


def test_quoted_cells_are_the_numbers_inside_them(tmp_path):
    """As spreadsheets and pandas' QUOTE_ALL write a CSV: every cell quoted."""
    s = _samples(50)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    quoted = tmp_path / "quoted.csv"
    lines = (tmp_path / "s.csv").read_text().splitlines()
    quoted.write_text("\n".join(",".join(f'"{c}"' for c in line.split(",")) for line in lines))
    got = read_measured(quoted)
    np.testing.assert_array_equal(got.rgb, plain.rgb)
    np.testing.assert_array_equal(got.wi, plain.wi)


@pytest.mark.parametrize("header", [
    "theta_i [deg],phi_i [deg],theta_o [deg],phi_o [deg],r,g,b",
    "theta_i (deg),phi_i (deg),theta_o (deg),phi_o (deg),r,g,b",
    "theta_i (°),phi_i (°),theta_o (°),phi_o (°),r,g,b",
    "theta_i/deg,phi_i/deg,theta_o/deg,phi_o/deg,r,g,b",
    "Theta_i deg,Phi_i deg,Theta_o deg,Phi_o deg,R,G,B",
    # the values' own unit, and channels spelled out
    "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,Red [1/sr],Green (1/sr),Blue [sr^-1]",
    # the angles in words, in either order, as instruments and people name them
    "Incident theta (deg),Incident phi (deg),Outgoing theta (deg),Outgoing phi (deg),R,G,B",
    "Incidence zenith angle [deg],Incidence azimuth angle [deg],Viewing zenith angle [deg],"
    "Viewing azimuth angle [deg],r,g,b",
    "θi (°),φi (°),θo (°),φo (°),r,g,b",
    "theta_light_deg,phi_light_deg,theta_view_deg,phi_view_deg,r,g,b",
    "Theta Incident/deg,Phi Incident/deg,Theta Detector/deg,Phi Detector/deg,r,g,b",
    "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,BRDF R,BRDF_green,Blue BRDF [1/sr]",
])
def test_a_unit_in_brackets_or_after_a_space_is_the_columns_unit(tmp_path, header):
    """As lab software and spreadsheets write a column's unit: the same samples as
    ``theta_i_deg`` (they were refused: "no column for theta_i, ...")."""
    s = _samples(50)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    other = tmp_path / "units.csv"
    other.write_text("\n".join([header, *lines[1:]]) + "\n")
    got = read_measured(other)
    np.testing.assert_array_equal(got.wi, plain.wi)
    np.testing.assert_array_equal(got.rgb, plain.rgb)


def test_samples_given_by_their_half_and_difference_angles(tmp_path):
    """A list indexed as the MERL table is (theta_h, theta_d, phi_d; phi_h 0 where
    absent): with phi_h, the same directions as the list of its four angles; without,
    the same half and difference angles (an isotropic list turned about the normal).
    It was "no column for theta_i, ...". Units as a direction's angles take them; two
    of the three are a refusal naming what is missing; the result says how it was read."""
    from brdffit.io.angles import dirs_to_half_diff
    from brdffit.io.readers import input_summary

    plain = read_measured(_write_all(tmp_path, _samples(60))["csv"])
    theta_h, theta_d, phi_d = dirs_to_half_diff(plain.wi, plain.wo)
    h = plain.wi + plain.wo
    phi_h = np.arctan2(h[:, 1], h[:, 0])

    def write(name, header, columns):
        rows = np.column_stack([*columns, plain.rgb])
        (tmp_path / name).write_text(
            "\n".join([header, *(",".join(map(repr, map(float, r))) for r in rows)]) + "\n")
        return tmp_path / name

    turned = read_measured(write("hd.csv", "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b",
                                 [np.degrees(a) for a in (theta_h, theta_d, phi_d)]))
    np.testing.assert_allclose(turned.rgb, plain.rgb)
    for got, want in zip(dirs_to_half_diff(turned.wi, turned.wo), (theta_h, theta_d, phi_d),
                         strict=True):
        np.testing.assert_allclose(got, want, atol=1e-9)
    assert input_summary(turned)["half_diff"] == ["theta_h_deg", "theta_d_deg", "phi_d_deg"]
    same = read_measured(write("hd4.csv", "theta_h [rad],theta_d [rad],phi_d [rad],"
                               "phi_h [rad],r,g,b", [theta_h, theta_d, phi_d, phi_h]))
    np.testing.assert_allclose(same.wi, plain.wi, atol=1e-9)
    np.testing.assert_allclose(same.wo, plain.wo, atol=1e-9)
    with pytest.raises(MeasurementsError, match="or theta_h, theta_d and phi_d .the half and "
                                                "difference angles.: the file has phi_d, "
                                                "theta_h of them"):
        read_measured(write("two.csv", "theta_h_deg,phi_d_deg,r,g,b",
                            [np.degrees(theta_h), np.degrees(phi_d)]))
    with pytest.raises(MeasurementsError, match="'theta_d' has no unit"):
        read_measured(write("unitless.csv", "theta_h_deg,theta_d,phi_d_deg,r,g,b",
                            [np.degrees(a) for a in (theta_h, theta_d, phi_d)]))
    # radians under a degrees header are refused as a direction's angles are (they put
    # every direction within 1.5 degrees of the normal, unsaid)
    with pytest.raises(MeasurementsError, match="said to be in degrees"):
        read_measured(write("radians.csv", "theta_h_deg,theta_d_deg,phi_d_deg,r,g,b",
                            [theta_h, theta_d, phi_d]))
    # datasets by those names (HDF5, and .npz alike), their unit in the name or an attribute
    with h5py.File(tmp_path / "hd.h5", "w") as f:
        for name, a in (("theta_h", theta_h), ("theta_d", theta_d), ("phi_d", phi_d)):
            f[f"{name}_rad"] = a
        f["phi_h"] = phi_h
        f["phi_h"].attrs["units"] = "radians"
        f["rgb"] = plain.rgb
    stored = read_measured(tmp_path / "hd.h5")
    np.testing.assert_allclose(stored.wi, plain.wi, atol=1e-9)
    np.testing.assert_allclose(stored.wo, plain.wo, atol=1e-9)
    assert input_summary(stored)["half_diff"] == ["theta_h_rad", "theta_d_rad", "phi_d_rad",
                                                  "phi_h"]
    np.savez(tmp_path / "hd.npz", theta_h_deg=np.degrees(theta_h),
             theta_d_deg=np.degrees(theta_d), phi_d_deg=np.degrees(phi_d), rgb=plain.rgb)
    np.testing.assert_allclose(read_measured(tmp_path / "hd.npz").rgb, plain.rgb)
    with h5py.File(tmp_path / "stray.h5", "w") as f:  # a direction's angle beside them
        for name, a in (("theta_h", theta_h), ("theta_d", theta_d), ("phi_d", phi_d),
                        ("theta_i", theta_h)):
            f[f"{name}_rad"] = a
        f["rgb"] = plain.rgb
    with pytest.raises(MeasurementsError, match="no dataset phi_i, theta_o, phi_o"):
        read_measured(tmp_path / "stray.h5")  # as a CSV's columns: not read past it
    with h5py.File(tmp_path / "two.h5", "w") as f:
        f["theta_h_rad"], f["phi_d_rad"], f["rgb"] = theta_h, phi_d, plain.rgb
    with pytest.raises(MeasurementsError, match="or theta_h, theta_d and phi_d .the half and "
                                                "difference angles.: it has theta_h, phi_d"):
        read_measured(tmp_path / "two.h5")


def test_an_angle_in_words_is_one_word_of_which_and_one_of_whose():
    """An angle named in words needs both: which angle (theta, zenith, phi, azimuth)
    and whose (incident, light; view, outgoing, detector). Rusinkiewicz's theta_h,
    theta_d and phi_d are no direction's; an elevation is not a zenith angle; two
    words of one kind, or another word, are no angle."""
    from brdffit.io.columns import angle_name

    def read(name):
        m = angle_name(name)
        return None if m is None else (m[1], m[2], m[3])

    assert read("incident (deg) theta") == ("theta", "i", "deg")  # a merged group's
    assert read("outgoing polar angle (°)") == ("theta", "o", "deg")
    assert read("theta of incidence") == ("theta", "i", None)
    assert read("phi (light)") == ("phi", "i", None)
    assert read("Incident light theta (deg)") == ("theta", "i", "deg")  # two words, one side
    assert read("Theta (in degrees)") is None  # "in" is no light's
    for other in ("theta_h", "theta_d", "phi_d", "zenith", "incident", "elevation incident",
                  "theta incident view", "theta phi incident", "theta deg rad incident",
                  "incident theta spread", "BRDF R", "red"):
        assert read(other) is None, other


def test_brdf_named_channels_beside_the_irradiance_are_read(tmp_path):
    """``BRDF R`` (read as r) still names a BRDF: the lab's irradiance column beside it
    is its record, not a sign of radiances (it was refused as one)."""
    s = _samples(20)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    other = tmp_path / "irradiance.csv"
    other.write_text("\n".join([lines[0].replace(",r,g,b", ",BRDF R,BRDF G,BRDF B")
                                 + ",irradiance", *(f"{line},100" for line in lines[1:])])
                     + "\n")
    np.testing.assert_array_equal(read_measured(other).rgb, plain.rgb)


@pytest.mark.parametrize("units", ["deg,deg,deg,deg,1/sr,1/sr,1/sr",
                                   "[°],[°],[°],[°],[1/sr],[1/sr],[1/sr]",
                                   "deg,deg,deg,deg,,,"])
def test_a_row_of_units_under_the_header_gives_the_columns_units(tmp_path, units):
    """Instruments export names and units as two header lines; read as one (the units
    row was "row 2 is not all numbers"). A name with its own unit keeps it."""
    s = _samples(40)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    for header in ("theta_i,phi_i,theta_o,phi_o,r,g,b", lines[0]):
        two = tmp_path / "two.csv"
        two.write_text("\n".join([header, units, *lines[1:]]) + "\n")
        got = read_measured(two)
        np.testing.assert_array_equal(got.wi, plain.wi)
        np.testing.assert_array_equal(got.rgb, plain.rgb)
    percent = tmp_path / "percent.csv"
    percent.write_text("\n".join(["theta_i,phi_i,theta_o,phi_o,r,g,b", "deg,deg,deg,deg,%,%,%",
                                  *lines[1:]]) + "\n")
    with pytest.raises(MeasurementsError, match="'r \\[%\\]'.*a unit that is not 1/sr"):
        read_measured(percent)


@pytest.mark.parametrize("delimiter", [";", "\t"])
def test_a_decimal_comma_is_read_where_the_cells_are_split_otherwise(tmp_path, delimiter):
    """A spreadsheet of a comma-decimal locale: ``0,25;30;...``. Read as numbers, and
    said in the fit's input; a file with points and commas in its numbers is refused,
    not guessed at (a point may be a thousands separator there)."""
    s = _samples(50)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    comma = tmp_path / "comma.csv"
    comma.write_text("\n".join(line.replace(",", delimiter).replace(".", ",")
                               for line in lines) + "\n")
    got = read_measured(comma)
    np.testing.assert_allclose(got.rgb, plain.rgb, rtol=1e-15)
    np.testing.assert_allclose(got.wi, plain.wi, rtol=1e-15, atol=1e-15)
    assert got.provenance["decimal_comma"] is True
    assert read_table(comma)[1]["decimal_comma"] is True
    assert "decimal_comma" not in read_table(tmp_path / "s.csv")[1]
    both = tmp_path / "both.csv"
    both.write_text("# angles: degrees\n"
                    f"{delimiter.join(COLUMNS.split(','))}{delimiter}r{delimiter}g{delimiter}b\n"
                    + delimiter.join(["10", "0", "1.020,5", "0", "0,5", "0,5", "0,5"]) + "\n")
    with pytest.raises(MeasurementsError, match="row 3 is not all numbers: .*'1.020,5' has "
                                                "a decimal comma, and row 3 a point"):
        read_measured(both)
    # the row named is the first that cannot be read, and the reason is the point elsewhere
    both.write_text("# angles: degrees\n"
                    f"{delimiter.join(COLUMNS.split(','))}{delimiter}r{delimiter}g{delimiter}b\n"
                    + delimiter.join(["10", "0", "20,5", "0", "0,5", "0,5", "0,5"]) + "\n"
                    + delimiter.join(["10", "0", "1.020,5", "0", "0,5", "0,5", "0,5"]) + "\n")
    with pytest.raises(MeasurementsError, match="row 3 is not all numbers: .*'20,5' has a "
                                                "decimal comma, and row 4 a point"):
        read_measured(both)
    quoted = tmp_path / "quoted.csv"
    quoted.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                      '"10","0","20,5","0","0,5","0,5","0,5"\n')
    with pytest.raises(MeasurementsError, match="'20,5' has a decimal comma in a file whose "
                                                "cells are split by commas"):
        read_measured(quoted)


def test_an_astm_file_split_by_blanks_or_tabs_reads_as_one_split_by_commas(tmp_path):
    """Files in the wild write ASTM rows and header lines with spaces or tabs (and
    CRLF): the same samples ("no VARS line" and "row 4 has 1 values" before)."""
    rows = ["0.1,0,0.2,0,1,2,3", "0.2,0,0.3,3.14,1,1,1", "0.3,0,0.4,1.0,0.5,1,1"]
    commas = tmp_path / "c.astm"
    commas.write_text("NUM_POINTS 3\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n"
                      + "\n".join(rows) + "\n")
    blanks = tmp_path / "b.astm"
    blanks.write_text("NUM_POINTS 3\nVARS theta_i, phi_i, theta_s, phi_s, R, G, B\n"
                      + "\n".join(r.replace(",", "  ") for r in rows) + "\n")
    tabs = tmp_path / "t.astm"
    tabs.write_bytes(("SOURCE\tlab\r\nNUM_POINTS\t3\r\nVARS\ttheta_i\tphi_i\ttheta_s\tphi_s"
                      "\tR\tG\tB\r\n" + "\r\n".join(r.replace(",", "\t") for r in rows)
                      + "\r\n").encode())
    want = read_measured(commas)
    for other in (blanks, tabs):
        got = read_measured(other)
        np.testing.assert_array_equal(got.rgb, want.rgb)
        np.testing.assert_array_equal(got.wo, want.wo)


def test_latin1_comments_and_header_are_read_and_binary_is_not(tmp_path):
    """Windows lab software writes Windows-1252: a comment or a header with ° or é is
    read (it was "not a text file"); a row of numbers with such a byte, or a binary
    file, is still refused."""
    s = _samples(50)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    latin = tmp_path / "latin.csv"
    latin.write_bytes("\n".join(["# mesuré à 25°C", "# angles: degrees",
                                 "theta_i (°),phi_i (°),theta_o (°),phi_o (°),r,g,b",
                                 *lines[1:]]).encode("cp1252"))
    np.testing.assert_array_equal(read_measured(latin).rgb, plain.rgb)
    astm = tmp_path / "latin.astm"
    astm.write_bytes(b"SAMPLE M\xfcller\nNUM_POINTS 1\nVARS theta_i,phi_i,theta_s,phi_s,R,G,B\n"
                     b"0.1,0,0.2,0,1,1,1\n")
    assert read_measured(astm).n == 1
    for name, data in (("row.csv", b"theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                                   b"10\xb0,0,20,0,1,1,1\n"),
                       ("png.csv", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe")):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(MeasurementsError, match=f"{name}: (line 2 is a row of numbers "
                                                    "with a character that is not UTF-8 "
                                                    "..°. as Windows-1252: '10°,0,20|a PNG "
                                                    "image, not a text sample list)"):
            read_measured(tmp_path / name)


@pytest.mark.parametrize("datasets, says", [
    # a (3, n) sigma reshaped to (n, 3) would hand each sample another's sigma
    ({"rgb": np.ones((4, 3)), "sigma": np.tile([0.1, 0.2, 0.3, 0.4], (3, 1))},
     "sigma has shape (3, 4): expected (4,) or (4, 3), one per sample"),
    ({"rgb": np.ones((4, 3)), "sigma": np.ones(8)}, "sigma has shape (8,)"),
    ({"rgb": np.ones((4, 3)), "sigma": np.ones(5)}, "sigma has shape (5,)"),
    ({"rgb": np.array([[b"x"] * 3] * 4)}, "dataset rgb holds text, not numbers"),
    ({"rgb": np.ones((4, 3)), "sigma": np.array([b"x"] * 4)}, "dataset sigma holds text"),
    ({"rgb": None}, "rgb is an HDF5 group, not a dataset"),
    # h5py's own words were the message ("Use () not None as shape arguments")
    ({"rgb": np.ones((4, 3)), "phi_o": h5py.Empty("f8")},
     "dataset phi_o is empty (an HDF5 null dataspace): it holds no values"),
    ({"rgb": np.ones((4, 3)), "value": np.ones(4)}, "datasets rgb and value"),
    # flattened, a (2, n) angle array paired one sample's angle with another's values
    ({"rgb": np.ones((4, 3)), "theta_i": np.full((2, 2), 10.0)},
     "dataset theta_i has shape (2, 2): expected (n,), one number per sample"),
    ({"value": np.ones((4, 2))}, "dataset value has shape (4, 2): expected (n,)"),
    ({"spectral": np.ones(4), "wavelengths": np.array([500.0])},
     "dataset spectral has shape (4,) and wavelengths (1,): expected (n, k) and (k,)"),
    ({"spectral": np.ones((4, 5)), "wavelengths": np.linspace(400.0, 700.0, 4)},
     "dataset spectral has shape (4, 5) and wavelengths (4,)"),
    ({"rgb": np.ones((4, 3)), "sigma": np.zeros(4)}, "sigma is 0 in 4 rows (first: row 1)"),
    ({"rgb": np.ones((4, 3)), "sigma": np.array([[0.1, 0.1, 0.0]] * 4)},
     "sigma's b channel is 0 in 4 rows"),
    # an uncertainty by another name than sigma was dropped unsaid, as a CSV column was
    ({"rgb": np.ones((4, 3)), "rgb_std": np.ones((4, 3))},
     "dataset 'rgb_std' looks like each value's uncertainty, which is read from a dataset "
     "sigma ((n, 3) or (n,)) or sigma_r, sigma_g, sigma_b"),
    ({"rgb": np.ones((4, 3)), "R_err": np.ones(4)}, "dataset 'R_err' looks like"),
    ({"value": np.ones(4), "Uncertainty": np.ones(4)}, "dataset 'Uncertainty' looks like"),
    ({"rgb": np.ones((4, 3)), "sigma_r": np.ones(4), "sigma_g": np.ones(4)},
     "datasets sigma_r, sigma_g: expected sigma, or sigma_r, sigma_g and sigma_b"),
    ({"value": np.ones(4), **{f"sigma_{c}": np.ones(4) for c in "rgb"}},
     "datasets sigma_r, sigma_g, sigma_b: expected one dataset sigma"),
    ({"spectral": np.ones((4, 2)), "wavelengths": np.array([500.0, 600.0]),
      "sigma": np.ones(4)}, "sigma of spectral samples: not read yet"),
])
def test_a_malformed_hdf5_file_gets_one_line_naming_it(tmp_path, datasets, says):
    path = _h5(tmp_path / "s.h5", **datasets)
    with pytest.raises(MeasurementsError) as e:
        read_measured(path)
    message = str(e.value)
    assert message.startswith(f"{path}: ") and says in message, message


def test_a_ragged_hdf5_dataset_is_named_as_one_not_as_text(tmp_path):
    path = _h5(tmp_path / "ragged.h5")
    with h5py.File(path, "a") as f:
        d = f.create_dataset("rgb", (4,), dtype=h5py.vlen_dtype(np.float64))
        for k in range(4):
            d[k] = np.ones(3 if k else 2)
    with pytest.raises(MeasurementsError, match="dataset rgb holds a variable-length array "
                                                "per row .a ragged list.: write it as one"):
        read_measured(path)


def test_an_hdf5_file_that_says_what_it_is_is_named_so(tmp_path):
    path = tmp_path / "results.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "brdffit-batch"
        f.create_group("tables")
    with pytest.raises(MeasurementsError, match="a brdffit-batch file, not a sample list"):
        read_measured(path)


def test_hdf5_sigma_per_sample_or_per_value(tmp_path):
    rgb = np.ones((4, 3))
    per_sample = read_measured(_h5(tmp_path / "a.h5", rgb=rgb, sigma=[0.1, 0.2, 0.3, 0.4]))
    np.testing.assert_array_equal(per_sample.sigma, np.repeat([[0.1], [0.2], [0.3], [0.4]], 3,
                                                              axis=1))
    per_value = np.arange(12.0).reshape(4, 3) + 1
    got = read_measured(_h5(tmp_path / "b.h5", rgb=rgb, sigma=per_value))
    np.testing.assert_array_equal(got.sigma, per_value)
    # one dataset per channel, as a CSV's sigma_r, sigma_g, sigma_b (they were dropped)
    got = read_measured(_h5(tmp_path / "c.h5", rgb=rgb,
                            **{f"sigma_{c}": per_value[:, k] for k, c in enumerate("rgb")}))
    np.testing.assert_array_equal(got.sigma, per_value)


def test_binning_the_bin_centres_of_a_table_gives_the_table_back():
    """Samples at the centres of a table's measured bins bin back into the same bins
    with the same values: moved by nothing (to rounding)."""
    rng = np.random.default_rng(3)
    values = rng.uniform(0.1, 1.0, (3, 90, 90, 180))
    mask = rng.uniform(size=(90, 90, 180)) < 0.01
    table = merl.MerlTable.from_values(values, mask)
    i = np.nonzero(mask)
    wi, wo = half_diff_to_dirs(*bin_centres(*i))
    samples = Measurements(np.asarray(wi), np.asarray(wo), values[:, i[0], i[1], i[2]].T)
    back, binning = samples.to_table()
    np.testing.assert_array_equal(back.mask, mask)
    np.testing.assert_allclose(back.rgb[:, mask], table.rgb[:, mask], rtol=1e-12)
    assert binning.bins == binning.samples == int(mask.sum()) and binning.most_in_a_bin == 1
    assert max(o["max"] for o in binning.offset_deg.values()) < 1e-6
    assert binning.spread_in_bins is None


def test_samples_in_one_bin_are_averaged_by_their_sigma():
    wi = np.array([[0.0, 0.0, 1.0]] * 3)
    samples = Measurements(wi, wi, np.array([[1.0] * 3, [2.0] * 3, [4.0] * 3]),
                           sigma=np.array([[1.0] * 3, [1.0] * 3, [0.0] * 3]))
    table, binning = samples.to_table()
    assert table.n_measured == 1 and binning.most_in_a_bin == 3
    # sigma 0 is the most certain by far: its value, to a part in a million
    assert table.rgb[:, table.mask][0, 0] == pytest.approx(4.0, rel=1e-5)
    plain, _ = Measurements(wi, wi, samples.rgb).to_table()
    assert plain.rgb[:, plain.mask][0, 0] == pytest.approx(7.0 / 3.0)


def test_only_sigmas_ratios_weigh_however_small_or_large_they_are():
    """A uniform sigma of 1e-160, squared, overflowed the weights to inf (a fit of NaNs)
    and one of 1e-200 underflowed to 0 (sigma silently ignored): weights and binned
    means depend on sigma's ratios alone."""
    from brdffit.fitting.samples import sample_weights

    rng = np.random.default_rng(5)
    wi = np.array([[0.0, 0.0, 1.0]] * 40)
    wo = np.array([[np.sin(t), 0.0, np.cos(t)] for t in np.linspace(0.0, 1.2, 40)])
    rgb = rng.uniform(0.05, 2.0, (40, 3))
    sigma = rng.uniform(0.5, 2.0, (40, 3))

    def weights(scale):
        w = sample_weights(Measurements(wi, wo, rgb, sigma=sigma * scale))
        return w / w.sum()

    def binned(scale):
        table, _ = Measurements(wi, wo, rgb, sigma=sigma * scale).to_table()
        return table.rgb[:, table.mask]

    for scale in (1e-200, 1e-160, 1e160):
        np.testing.assert_allclose(weights(scale), weights(1.0), rtol=1e-12)
        np.testing.assert_allclose(binned(scale), binned(1.0), rtol=1e-12)
    uniform = sample_weights(Measurements(wi, wo, rgb))
    assert not np.allclose(weights(1e-200), uniform / uniform.sum())


def test_a_fit_of_samples_recovers_their_material(tmp_path):
    """40,000 noisy samples of a GGX material, as a lab's CSV: the fit of the binned
    table finds the material (binning moves each sample by a bin's half-width, which
    costs the lobe's scale a few per cent), and the fit carries the input's report."""
    import jax.numpy as jnp

    from brdffit import models
    from brdffit.fitting.pipeline import fit
    from brdffit.request import FitRequest, run

    theta_i, phi_i, theta_o, phi_o, _ = _samples(40_000, seed=1)
    truth = {"kd": [0.3, 0.15, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.12, "f0": 0.3}
    m = models.get("ggx")
    p = {k: jnp.asarray(v) for k, v in m.check_params(truth).items()}
    from brdffit.io.measurements import direction

    f = np.asarray(m(p, jnp.asarray(direction(theta_i, phi_i)),
                     jnp.asarray(direction(theta_o, phi_o))))
    f = f * (1 + 0.02 * np.random.default_rng(2).normal(size=f.shape))
    path = tmp_path / "lab.csv"
    rows = np.column_stack([theta_i, phi_i, theta_o, phi_o, f])
    path.write_text("theta_i_rad,phi_i_rad,theta_o_rad,phi_o_rad,r,g,b\n"
                    + "\n".join(",".join(f"{x:.9g}" for x in r) for r in rows) + "\n")
    table, measured_input = read_table(path)
    assert measured_input["format"] == "csv" and measured_input["samples"] == 40_000
    assert measured_input["binning"]["bins"] == table.n_measured
    assert "binned 40000 samples" in measured_input["note"]
    r = fit(table, "ggx", samples=4096)
    assert r.converged
    assert r.params["alpha"] == pytest.approx(0.12, rel=0.03)
    np.testing.assert_allclose(r.params["kd"], truth["kd"], rtol=0.03, atol=2e-3)
    np.testing.assert_allclose(r.params["ks"], truth["ks"], rtol=0.05)
    report = run(table, FitRequest.of("ggx", samples=4096),
                 measured_input=measured_input)
    assert report.chosen_fit.input == measured_input
    assert report.chosen_fit.to_dict()["input"]["format"] == "csv"


def test_spectral_samples_are_projected_to_rgb_under_d65(tmp_path):
    """Spectral columns named by wavelength (CSV) or a spectral dataset (HDF5) become
    linear sRGB under D65: a flat spectrum stays grey at its level, a long-wavelength
    one is red; the provenance and the fit's input say how. Spectra short of
    420-680 nm, or beside RGB columns, are refused in one line."""
    import h5py

    from brdffit.io import spectra

    lam = np.arange(400, 701, 20)
    flat = np.full(lam.size, 0.3)
    red = np.where(lam > 600, 0.8, 0.05)
    head = "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg," + ",".join(f"{x}nm" for x in lam)
    path = tmp_path / "spectral.csv"
    path.write_text(head + "\n" + "\n".join(
        "30,0,40,180," + ",".join(f"{v:g}" for v in spec) for spec in (flat, red)) + "\n")
    m = read_measured(path)
    np.testing.assert_allclose(m.rgb[0], [0.3, 0.3, 0.3], rtol=1e-9)
    assert m.rgb[1, 0] > 10 * m.rgb[1, 1] and m.rgb[1, 0] > 10 * m.rgb[1, 2]
    assert m.provenance["spectral"]["illuminant"] == "D65"
    assert m.provenance["spectral"]["wavelengths_nm"] == [400.0, 700.0, lam.size]
    from brdffit.io.readers import input_summary

    assert input_summary(m)["spectral"]["observer"] == "CIE 1931 2 deg"
    h5 = tmp_path / "spectral.h5"
    with h5py.File(h5, "w") as f:
        for name, v in (("theta_i", [30.0, 30.0]), ("phi_i", [0.0, 0.0]),
                        ("theta_o", [40.0, 40.0]), ("phi_o", [180.0, 180.0])):
            f.create_dataset(name, data=v).attrs["units"] = "degrees"
        f.create_dataset("spectral", data=np.stack([flat, red]))
        f.create_dataset("wavelengths", data=lam.astype(float))
    np.testing.assert_allclose(read_measured(h5).rgb, m.rgb, rtol=1e-12)
    # a wavelengths dataset longest first: each value keeps its wavelength (was refused;
    # a CSV's columns are sorted by their names already)
    with h5py.File(h5, "w") as f:
        for name, v in (("theta_i", [30.0, 30.0]), ("phi_i", [0.0, 0.0]),
                        ("theta_o", [40.0, 40.0]), ("phi_o", [180.0, 180.0])):
            f.create_dataset(name, data=v).attrs["units"] = "degrees"
        f.create_dataset("spectral", data=np.stack([flat, red])[:, ::-1])
        f.create_dataset("wavelengths", data=lam[::-1].astype(float))
    b = read_measured(h5)
    np.testing.assert_allclose(b.rgb, m.rgb, rtol=1e-12)
    assert b.provenance["spectral"]["wavelength_order"].startswith("not increasing")
    assert "wavelength_order" not in m.provenance["spectral"]
    with pytest.raises(MerlFormatError, match="finite and distinct"):
        spectra.to_rgb(np.ones((1, 3)), [500.0, 400.0, 500.0], "twice.csv")
    short = tmp_path / "short.csv"
    short.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,450nm,550nm,650nm\n"
                     "30,0,40,180,1,1,1\n")
    with pytest.raises(MerlFormatError, match="span 450-650 nm; projecting to RGB needs"):
        read_measured(short)
    # wavelengths in micrometres: said
    microns = tmp_path / "microns.npz"
    np.savez(microns, theta_i_deg=[30.0], phi_i_deg=[0.0], theta_o_deg=[40.0], phi_o_deg=[180.0],
             spectral=np.ones((1, 5)), wavelengths=np.linspace(0.38, 0.78, 5))
    with pytest.raises(MerlFormatError, match=r"span 0.38-0.78 nm \(micrometres\?"):
        read_measured(microns)
    # three lasers span the range, but the colour between them would be a straight line
    lasers = tmp_path / "lasers.csv"
    lasers.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,405nm,532nm,690nm\n"
                      "30,0,40,180,1,1,1\n")
    with pytest.raises(MerlFormatError, match="3 wavelengths, 158 nm apart between 532 and "
                                              "690 nm.*at most 100 nm apart"):
        read_measured(lasers)
    steps = tmp_path / "steps.csv"  # a multispectral camera's 50 nm steps read
    steps.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,"
                     + ",".join(f"{w}nm" for w in range(400, 751, 50)) + "\n30,0,40,180,"
                     + ",".join(["0.5"] * 8) + "\n")
    np.testing.assert_allclose(read_measured(steps).rgb, 0.5, rtol=0.02)
    both = tmp_path / "both.csv"
    both.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,450nm\n"
                    "30,0,40,180,1,1,1,1\n")
    with pytest.raises(MerlFormatError, match="keep one kind"):
        read_measured(both)
    assert spectra.wavelength_of("theta_i_deg") is None
    # a wavelength's word with its number names a spectral column, in nm (lambda_400,
    # ... were two columns "saying which wavelength a row holds: keep one")
    for name, nm in (("lambda_400", 400.0), ("WL450", 450.0), ("λ_532.5", 532.5),
                     ("wavelength_600nm", 600.0)):
        assert spectra.wavelength_of(name) == nm, name
    assert spectra.wavelength_of("lambda") is None and spectra.wavelength_of("450") is None
    steps.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,"
                     + ",".join(f"lambda_{w}" for w in range(400, 751, 50)) + "\n30,0,40,180,"
                     + ",".join(["0.5"] * 8) + "\n")
    np.testing.assert_allclose(read_measured(steps).rgb, 0.5, rtol=0.02)


# -- files as they come: a sweep of 213 malformed and unusual inputs (2026-12-04) -----------


def test_a_long_one_line_file_is_refused_without_guessing_its_delimiter_from_all_of_it(
        tmp_path, monkeypatch):
    """csv.Sniffer's time grows with the square of its text: a one-line JSON export of
    517 KB named .txt ran for minutes before its refusal. The delimiter is guessed from
    the header's first SNIFF_CHARS; its 36,000 "columns" are refused on their count."""
    import csv

    from brdffit.io import text_samples

    sniffed = []
    sniff = csv.Sniffer.sniff
    monkeypatch.setattr(csv.Sniffer, "sniff",
                        lambda self, text, *a, **k: sniffed.append(len(text))
                        or sniff(self, text, *a, **k))
    p = tmp_path / "records.txt"
    p.write_text(", ".join(f"theta_i {k}, phi_i {k}, value {k}" for k in range(12000)))
    with pytest.raises(MeasurementsError, match="the header names 36,000 columns") as e:
        read_measured(p)
    assert sniffed == [text_samples.SNIFF_CHARS]
    assert len(str(e.value)) < 600
    # the JSON export itself is said to be JSON before any delimiter is guessed
    sniffed.clear()
    p.write_text("[" + ", ".join(f'{{"theta_i": {k}, "phi_i": {k}, "value": {k}}}'
                                 for k in range(12000)) + "]")
    with pytest.raises(MeasurementsError, match="a JSON document, not a measured table"):
        read_measured(p)
    assert sniffed == []


@pytest.mark.parametrize("name, head", [
    ("a.csv", "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,0,1,1,1\n"),
    ("a.astm", "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n0.1,0,0.2,0,1,1,1\n")],
    ids=["csv", "astm"])
def test_a_quote_left_open_names_its_row(tmp_path, name, head):
    """A quote that opens a cell and never closes: that row is named; read as one CSV
    stream, the cell swallowed every line after it, and past 128 KiB the csv module's
    "field larger than field limit" came out as a traceback."""
    row = head.splitlines()[-1]
    path = tmp_path / name
    path.write_text(head + '"' + row + "\n" + (row + "\n") * 20000)
    with pytest.raises(MeasurementsError, match="row 3 has a quote that is not closed where "
                                                "its cell ends"):
        read_measured(path)


def test_text_as_excel_and_numpy_write_it(tmp_path):
    """UTF-16 with its mark (Excel's "Unicode text", tab-separated), Excel's 'sep=;'
    line, a UTF-8 mark before Windows-1252 comments, a comment holding U+2028, and an
    ASTM file named .txt read as the same samples; UTF-16 without a mark is refused as
    what it is."""
    s = _samples(60)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    lines = (tmp_path / "s.csv").read_text().splitlines()
    variants = {
        "excel.txt": "\r\n".join(line.replace(",", "\t") for line in lines).encode("utf-16"),
        "sep.csv": "\n".join(["sep=;", *(line.replace(",", ";") for line in lines)]).encode(),
        "bom.csv": b"\xef\xbb\xbf" + "\n".join(["# mesuré", *lines]).encode("cp1252"),
        "u2028.csv": "\n".join(["# a comment\u2028theta, with a separator", *lines]).encode(),
    }
    for name, data in variants.items():
        (tmp_path / name).write_bytes(data)
        got = read_measured(tmp_path / name)
        np.testing.assert_array_equal(got.rgb, plain.rgb, err_msg=name)
    astm = read_measured(_write_all(tmp_path, s)["astm"])
    (tmp_path / "astm.txt").write_bytes((tmp_path / "s.astm").read_bytes())
    assert read_measured(tmp_path / "astm.txt").provenance["format"] == "astm"
    np.testing.assert_array_equal(read_measured(tmp_path / "astm.txt").rgb, astm.rgb)
    (tmp_path / "nomark.csv").write_bytes("\n".join(lines).encode("utf-16-le"))
    with pytest.raises(MeasurementsError, match="holds NUL bytes: binary, or UTF-16 without"):
        read_measured(tmp_path / "nomark.csv")
    # a file named as another layout is read as what it is, or named by its first bytes
    (tmp_path / "astm.csv").write_bytes((tmp_path / "s.astm").read_bytes())
    np.testing.assert_array_equal(read_measured(tmp_path / "astm.csv").rgb, astm.rgb)
    (tmp_path / "h5.csv").write_bytes((tmp_path / "s.h5").read_bytes())
    assert read_measured(tmp_path / "h5.csv").provenance["format"] == "hdf5"
    table = merl.MerlTable.from_values(np.full((3, 90, 90, 180), 0.1))
    merl.write(tmp_path / "table.csv", table)
    assert isinstance(read_measured(tmp_path / "table.csv"), merl.MerlTable)
    # a CSV saved as .xlsx (it was "not a readable Excel workbook (File is not a zip
    # file)"); a gzip archive is told to be decompressed, whatever its name
    for fake in ("csv.xlsx", "csv.npz"):
        (tmp_path / fake).write_bytes((tmp_path / "s.csv").read_bytes())
        assert read_measured(tmp_path / fake).provenance["format"] == "csv"
    import gzip

    (tmp_path / "s.csv.gz").write_bytes(gzip.compress((tmp_path / "s.csv").read_bytes()))
    with pytest.raises(MerlFormatError, match=r"a gzip archive.*\(decompress it first\)"):
        read_measured(tmp_path / "s.csv.gz")
    # a fit's JSON given as the table (brdffit export --measured fit.json)
    (tmp_path / "fit.json").write_text('{"schema": "brdffit.fit/3", "params": [null]}')
    with pytest.raises(MeasurementsError, match="a JSON document, not a measured table"):
        read_measured(tmp_path / "fit.json")
    # a zip archive that is no workbook (test_an_excel_sheet_... reads one named .csv)
    (tmp_path / "book.csv").write_bytes(b"PK\x03\x04" + bytes(60))
    with pytest.raises(MeasurementsError, match="a zip archive, not a text sample list .by its "
                                                "first bytes.$"):
        read_measured(tmp_path / "book.csv")


def test_radians_said_to_be_degrees_are_refused(tmp_path):
    """Radians under _deg names read as a list within 1.6 degrees of the normal, and
    were fitted; degrees under _rad names are refused by the azimuth's bound."""
    s = _samples(100)
    rows = np.column_stack([*s[:4], s[4]])
    p = tmp_path / "rad.csv"
    p.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    with pytest.raises(MeasurementsError, match="said to be in degrees, but all 100 samples' "
                                                "polar angles are within 1.5708"):
        read_measured(p)
    h5 = _h5(tmp_path / "rad.h5", n=100, rgb=np.ones((100, 3)),
             **dict(zip(("theta_i", "phi_i", "theta_o", "phi_o"), s[:4], strict=True)))
    with pytest.raises(MeasurementsError, match="said to be in degrees"):
        read_measured(h5)
    # polar angles in radians beside azimuths in degrees (a lab's habit): fitted as
    # degrees and called good; and a short list, fitted with lambert
    mixed = rows.copy()
    mixed[:, [1, 3]] = np.degrees(mixed[:, [1, 3]]) + 40.0
    p.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in mixed) + "\n")
    with pytest.raises(MeasurementsError, match="polar angles in radians beside azimuths "
                                                "in degrees"):
        read_measured(p)
    p.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in rows[:5]) + "\n")
    with pytest.raises(MeasurementsError, match="all 5 samples' polar angles"):
        read_measured(p)
    # named per column, the same numbers are read
    p.write_text("theta_i_rad,phi_i_deg,theta_o_rad,phi_o_deg,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in mixed) + "\n")
    assert read_measured(p).n == 100
    # degrees under _rad names: "theta_i_rad is below the horizon in 67 rows", the value
    # and the unit unsaid; now the unit is asked, with the largest value
    deg = np.column_stack([*(np.degrees(a) for a in s[:4]), s[4]])
    p.write_text("theta_i_rad,phi_i_rad,theta_o_rad,phi_o_rad,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in deg) + "\n")
    with pytest.raises(MeasurementsError, match=r"said to be in radians, but [\d,]+ of the 200 "
                                                r"polar angles are past pi/2 .up to [\d.]+., "
                                                "and all are within 90: degrees\\?"):
        read_measured(p)
    few = rows.copy()  # radians, two rows past the horizon: refused row by row, as before
    few[:2, 0] = 2.0
    p.write_text("theta_i_rad,phi_i_rad,theta_o_rad,phi_o_rad,r,g,b\n"
                 + "\n".join(",".join(repr(float(x)) for x in r) for r in few) + "\n")
    with pytest.raises(MeasurementsError, match="theta_i_rad is below the horizon"):
        read_measured(p)


def test_hdf5_links_to_nothing_huge_declarations_and_foreign_attributes(tmp_path):
    """A dangling or external link is named (it was a KeyError); a dataset declaring
    10^12 rows or numbers is refused before it is read (numpy was asked for 7 TiB); an
    attribute that is not UTF-8 is named; a provenance attribute that is not
    brdffit's does not replace what was read."""
    link = _h5(tmp_path / "link.h5", rgb=np.ones((4, 3)))
    with h5py.File(link, "a") as f:
        del f["theta_i"]
        f["theta_i"] = h5py.SoftLink("/nowhere")
    with pytest.raises(MeasurementsError, match="theta_i is a link to an object that cannot "
                                                "be opened"):
        read_measured(link)
    ext = _h5(tmp_path / "ext.h5", rgb=np.ones((4, 3)))
    with h5py.File(ext, "a") as f:
        del f["rgb"]
        f["rgb"] = h5py.ExternalLink("missing.h5", "/rgb")
    with pytest.raises(MeasurementsError, match="rgb is an external link to another file"):
        read_measured(ext)
    huge = _h5(tmp_path / "huge.h5", rgb=np.ones((4, 3)))
    with h5py.File(huge, "a") as f:
        del f["theta_i"]
        f.create_dataset("theta_i", shape=(10**12,), dtype="f8", chunks=(1024,))
        f["theta_i"].attrs["units"] = "degrees"
    with pytest.raises(MeasurementsError, match=r"declare 1,000,000,000,000 samples"):
        read_measured(huge)  # more rows than a sample list holds: refused by its shape
    wide = _h5(tmp_path / "wide.h5", spectral=np.ones((4, 5)))
    with h5py.File(wide, "a") as f:  # a dataset of another shape: by its numbers
        f.create_dataset("wavelengths", shape=(10**12,), dtype="f8", chunks=(1024,))
    with pytest.raises(MeasurementsError, match=r"wavelengths holds 1,000,000,000,000 numbers"):
        read_measured(wide)
    latin = _h5(tmp_path / "latin.h5", rgb=np.ones((4, 3)))
    with h5py.File(latin, "a") as f:
        f["theta_i"].attrs["units"] = np.bytes_(b"radi\xe1ns")
    with pytest.raises(MeasurementsError, match=r"attribute units is not UTF-8 text"):
        read_measured(latin)
    rgb = np.column_stack([np.linspace(0.1, 1, 4)] * 2 + [np.ones(4)])
    for stored in ('{"instrument": "goniometer 2", "operator": "A"}',
                   '{"format": NaN, "decimal_comma": true}', '{"format": "csv", "channels": 1}'):
        lab = _h5(tmp_path / "lab.h5", rgb=rgb)
        with h5py.File(lab, "a") as f:
            f.attrs["provenance"] = stored
        got = read_measured(lab)
        assert got.provenance["format"] in ("hdf5", "csv") and "channels" in got.provenance
        assert got.provenance["channels"] == 3 and "decimal_comma" not in got.provenance


def test_an_endless_stream_and_a_symlink_loop_are_named(tmp_path, monkeypatch):
    """A stream is copied up to MAX_STREAM_BYTES, then refused (/dev/zero was copied
    until the disk was full); a symbolic link loop is said in its own words."""
    import os

    from brdffit.io import readers

    monkeypatch.setattr(readers, "MAX_STREAM_BYTES", 3 * 2**20)
    with pytest.raises(MerlFormatError, match="a stream longer than 3,145,728 bytes"):
        read_measured("/dev/zero")
    os.symlink(tmp_path / "b.csv", tmp_path / "a.csv")
    os.symlink(tmp_path / "a.csv", tmp_path / "b.csv")
    with pytest.raises(MerlFormatError, match="cannot read: Too many levels of symbolic links"):
        read_measured(tmp_path / "a.csv")


def test_an_error_naming_a_file_with_a_line_break_is_one_line(tmp_path, capsys):
    """The CLI's error is one line, also where the file's name holds a line break (its
    own line had held the rest of the message)."""
    from brdffit.cli import main as cli_main

    path = tmp_path / "bad\nname.csv"
    path.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n")
    assert cli_main(["fit", str(path), "--model", "lambert"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "bad\\nname.csv: no data" in err, err


@pytest.mark.parametrize("values, says", [
    (np.ones((5, 2)), "values have shape (5, 2): expected (n,) or (n, 3)"),
    (np.ones((5, 3, 1)), "values have shape (5, 3, 1)"),
    (None, "no values"),
    (np.ones(4), "4 values but angles of [5, 5, 5, 5] rows"),
])
def test_values_of_another_shape_are_named_by_it(values, says):
    """Two channels were "5 values but angles of [5, 5, 5, 5] rows", which they are."""
    angles = [np.full(5, 0.3)] * 4
    with pytest.raises(MeasurementsError, match=re.escape(says)):
        Measurements.from_angles(*angles, values)


def test_a_header_of_a_million_columns_is_refused_before_any_is_read(tmp_path, monkeypatch):
    """A 40 MB header of 20 million columns took 41 s to refuse (column by column) in
    the service's own process: it is refused on its count, no column looked at."""
    from brdffit.io import text_samples

    wide = tmp_path / "wide.csv"
    wide.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b,"
                    + ",".join(f"x{k}" for k in range(1_000_000)) + "\n")
    looked = []
    monkeypatch.setattr(text_samples, "angle_name", lambda name: looked.append(name))
    with pytest.raises(MeasurementsError, match="wide.csv: the header names 1,000,007 columns; "
                                                ".* at most 10,000 are read"):
        read_measured(wide)
    assert looked == []


def test_a_spreadsheets_leftovers_and_a_column_of_notes_are_left_alone(tmp_path):
    """As Excel exports a sheet: empty columns after the last one (`,,,`), rows of
    empty cells after the data, and a column of text beside the numbers (a sample's
    name): read as the same samples (each was refused: a header column without a
    name, a row of the wrong width, a row not all numbers). A used column that is not a
    number is still refused."""
    s = _samples(40)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    header, *rows = (tmp_path / "s.csv").read_text().splitlines()
    sheet = tmp_path / "sheet.csv"
    sheet.write_text("\n".join([f"{header},note,,", *(f"{r},ok v1.2,," for r in rows),
                                ",,,,,,,,,", ",,,,,,,,,"]) + "\n")
    got = read_measured(sheet)
    np.testing.assert_array_equal(got.rgb, plain.rgb)
    np.testing.assert_array_equal(got.wo, plain.wo)
    assert "empty_rows" not in got.provenance  # after the data: a sheet's leftovers
    # a row of empty cells among the data is skipped too, and counted (it was unsaid)
    sheet.write_text("\n".join([header, *rows[:5], ",,,,,,", *rows[5:]]) + "\n")
    got = read_measured(sheet)
    assert got.n == 40 and got.provenance["empty_rows"] == 1
    sheet.write_text("\n".join([f"{header},note", f"{rows[0]},x", f"{rows[1][:-3]}y,x"]))
    with pytest.raises(MeasurementsError, match="row 3 is not all numbers"):
        read_measured(sheet)


def test_samples_are_read_only_and_the_callers_arrays_stay_theirs():
    """As a MerlTable's: a fit keeps what it derives with the Measurements object, so a
    sample list changed in place was fitted from the old samples."""
    s = _samples(20)
    values = np.array(s[4])
    m = Measurements.from_angles(*s[:4], values)
    with pytest.raises(ValueError, match="read-only"):
        m.rgb[0] = 1.0
    values *= 2  # the caller's array is not the samples'
    np.testing.assert_array_equal(m.rgb, s[4])
    own = Measurements(np.array(m.wi), np.array(m.wo), np.array(m.rgb))
    assert not (own.wi.flags.writeable or own.rgb.flags.writeable)


def test_a_polar_angle_a_rounding_below_zero_is_the_normal():
    """An instrument's -0.0001 degrees at normal incidence is read as 0 (it was
    refused as negative, while 90.00001 degrees was read as 90); 90.004 degrees is 90
    as -0.004 is 0 (it was refused as below the horizon), 90.02 is still refused."""
    angles = [np.radians([-0.0001, 10.0]), np.zeros(2), np.radians([20.0, -0.005]),
              np.zeros(2)]
    m = Measurements.from_angles(*angles, np.ones(2))
    np.testing.assert_array_equal(m.wi[0], [0.0, 0.0, 1.0])
    np.testing.assert_array_equal(m.wo[1], [0.0, 0.0, 1.0])
    grazing = [np.radians([90.004, 10.0]), np.zeros(2), np.radians([20.0, 30.0]), np.zeros(2)]
    assert Measurements.from_angles(*grazing, np.ones(2)).wi[0, 2] == pytest.approx(0, abs=1e-12)
    grazing[0] = np.radians([90.02, 10.0])
    with pytest.raises(MeasurementsError, match="below the horizon"):
        Measurements.from_angles(*grazing, np.ones(2))


def test_a_list_over_max_samples_is_refused_before_a_number_is_read(tmp_path, monkeypatch):
    """A 2.7 MB gzip-compressed HDF5 file declaring 2e7 samples of one value was
    decompressed whole (GBs) and fitted for minutes: its datasets' declared rows are
    weighed against MAX_SAMPLES before any is read. A text list's rows are counted
    before they are parsed."""
    from brdffit.io import measurements, named_arrays, readers

    n = measurements.MAX_SAMPLES + 1
    bomb = tmp_path / "bomb.h5"
    with h5py.File(bomb, "w") as f:  # declared, never written: each reads as 0.5
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            f.create_dataset(name, shape=(n,), dtype="f8", fillvalue=0.5, chunks=(2**16,),
                             compression="gzip").attrs["units"] = "radians"
        f.create_dataset("rgb", shape=(n, 3), dtype="f8", fillvalue=0.3, chunks=(2**16, 3),
                         compression="gzip")
    assert bomb.stat().st_size < 100_000

    def no_reading(*args):
        raise AssertionError("a dataset was read")

    with monkeypatch.context() as m:
        m.setattr(named_arrays, "_numeric", no_reading)
        with pytest.raises(MeasurementsError) as e:
            read_measured(bomb)
    assert str(e.value) == (f"{bomb}: its datasets declare {n:,} samples: more than a sample "
                            f"list read here ({n - 1:,}; a MERL table has 1,458,000 bins); bin "
                            "it onto the MERL grid or thin it first")
    # named .csv, an HDF5 file is read as one, and so weighed as one
    assert readers.declared_samples(bomb) == readers.declared_samples(bomb, "b.csv") == n
    # values declaring more rows than the angles: weighed too
    few = _h5(tmp_path / "few.h5")
    with h5py.File(few, "a") as f:
        f.create_dataset("rgb", shape=(n, 3), dtype="f8", chunks=(2**16, 3))
    with pytest.raises(MeasurementsError, match=f"its datasets declare {n:,} samples"):
        read_measured(few)
    monkeypatch.setattr(measurements, "MAX_SAMPLES", 10)
    rows = tmp_path / "rows.csv"
    rows.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                    + "".join(f"10,0,{k},0,1,1,1\n" for k in range(11)))
    with pytest.raises(MeasurementsError, match="rows.csv: 11 samples: more than a sample "
                                                "list read here \\(10;"):
        read_measured(rows)
    with pytest.raises(MeasurementsError, match="11 samples: more than"):
        Measurements.from_angles(*np.zeros((4, 11)), np.ones(11))
    rows.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                    + "".join(f"10,0,{k},0,1,1,1\n" for k in range(10)))
    assert read_measured(rows).n == 10


def test_a_unit_suffix_is_read_from_the_end_of_any_name(tmp_path):
    """A column name's unit suffix (``[deg]``, ``(deg)``, ``/deg``, `` deg``) is read
    as the one regular expression that read it before did, on every name of up to five
    characters of a small alphabet; and in time linear in the name: that expression
    split a run of spaces in cubic many ways (a 16 KB header took 110 s to read)."""
    import itertools

    from brdffit.io.columns import unit_suffixed as _unit_suffixed

    def as_before(name: str) -> str:
        name = name.replace("°", "deg").replace("º", "deg")
        m = re.fullmatch(r"(.*?)\s*(?:\[\s*(\w+)\s*\]|\(\s*(\w+)\s*\)|/\s*(\w+)|\s+(\w+))",
                         name)
        return name if m is None else f"{m[1]}_{next(u for u in m.groups()[1:] if u)}"

    for n in range(6):
        for name in map("".join, itertools.product("a_ /[(])\t°", repeat=n)):
            assert _unit_suffixed(name) == as_before(name), repr(name)
    # a name of 20,000 spaces (hours, as it was) beside the angles: read, and ignored
    s = _samples(60)
    lines = _write_all(tmp_path, s)["csv"].read_text().splitlines()
    long = tmp_path / "long.csv"
    long.write_text("\n".join([lines[0] + ",note" + " " * 20_000 + "x!",
                               *(line + ",a" for line in lines[1:])]) + "\n")
    np.testing.assert_array_equal(read_measured(long).wi, read_measured(tmp_path / "s.csv").wi)


def test_azimuths_in_radians_under_a_degrees_header_are_noted_not_refused(tmp_path):
    """Azimuths said to be degrees that all lie within 2 pi and are mostly not whole
    numbers are radians under a degrees header, most likely: read (a list measured near
    its plane of incidence reads so too), with what the fit's note says of them. Real
    degrees, and whole degrees near the plane, are not."""
    theta_i, phi_i, theta_o, phi_o, rgb = _samples(200)
    rows = np.column_stack([np.degrees(theta_i), phi_i, np.degrees(theta_o), phi_o, rgb])
    path = tmp_path / "rad.csv"
    path.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                    + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    said = read_measured(path).provenance
    assert said["azimuths_within_deg"] == pytest.approx(phi_o.max())
    assert "azimuths_within_deg" not in read_measured(_write_all(tmp_path, (
        theta_i, phi_i, theta_o, phi_o, rgb))["csv"]).provenance
    rows[:, 3] = np.round(rows[:, 3])  # whole degrees, 0 to 6: a plane's neighbourhood
    path.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n"
                    + "\n".join(",".join(repr(float(x)) for x in r) for r in rows) + "\n")
    assert "azimuths_within_deg" not in read_measured(path).provenance
    # an in-plane list, phi_o 0 or pi in radians under degrees (it reaches no further
    # than pi): noted too; the same list in degrees, 0 or 180, is not
    rows[:, 1], rows[:, 3] = 0.0, np.where(np.arange(len(rows)) % 2, np.pi, 0.0)
    for pi, noted in (("3.14159265", True), ("3.1416", True), ("180", False)):
        path.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n" + "\n".join(
            ",".join(pi if (j == 3 and x) else repr(float(x)) for j, x in enumerate(r))
            for r in rows) + "\n")
        said = read_measured(path).provenance
        assert ("azimuths_within_deg" in said) == noted, pi


def test_spectra_with_thousands_of_wavelengths_project_as_interpolation_does():
    """Each wavelength's share of the projection's grid is ``np.interp`` of its unit
    vector (built that way, 6,000 wavelengths took minutes), held at the end values."""
    from brdffit.io import spectra

    rng = np.random.default_rng(2)
    for k in (2, 3, 17, 81):
        lam = np.sort(rng.choice(np.arange(300.0, 900.0, 0.5), k, replace=False))
        expected = np.stack([np.interp(spectra.GRID, lam, np.eye(k)[j]) for j in range(k)])
        np.testing.assert_allclose(spectra.interpolation_matrix(lam, spectra.GRID), expected,
                                   atol=1e-15)
    lam = np.linspace(380.0, 780.0, 6000)
    rgb, info = spectra.to_rgb(np.full((4, lam.size), 0.1), lam, "wide.h5")
    assert info["wavelengths_nm"] == [380.0, 780.0, 6000]
    np.testing.assert_allclose(rgb, 0.1, rtol=0.02)  # a flat spectrum is grey


def test_a_sigma_far_below_the_others_weighs_much_but_finitely():
    """A sigma of 1e-300 beside others of 0.01: its weight was 1 / 0 (its bin NaN,
    dropped unsaid, with numpy's warnings); it is floored at a millionth of the median."""
    import warnings

    wi = np.array([[0.0, 0.0, 1.0]] * 40)
    wo = np.array([[np.sin(t), 0.0, np.cos(t)] for t in np.linspace(0.0, 1.2, 40)])
    rgb = np.full((40, 3), 0.3)
    sigma = np.full((40, 3), 0.01)
    sigma[0] = 1e-300
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        table, _ = Measurements(wi, wo, rgb, sigma=sigma).to_table()
    assert np.all(np.isfinite(table.rgb[:, table.mask]))
    np.testing.assert_allclose(table.rgb[:, table.mask], 0.3)


def test_an_hdf5_list_is_read_from_its_own_file_alone(tmp_path):
    """An uploaded HDF5 file whose values live elsewhere (external storage, an external
    link, a virtual dataset) made the service read files on the server (a FIFO there
    hung the upload); a soft link to itself was a RuntimeError: each is refused, named."""
    import os

    n = 50
    np.full((n, 3), 0.123456789).tofile(tmp_path / "secret.bin")
    with h5py.File(tmp_path / "target.h5", "w") as f:
        f["rgb"] = np.full((n, 3), 0.2)
    os.mkfifo(tmp_path / "fifo")

    def listed(name, values):
        s = _samples(n)
        with h5py.File(tmp_path / name, "w") as f:
            for key, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), s[:4], strict=True):
                f[key] = np.degrees(a)
            f.attrs["units"] = "degrees"
            values(f)
        return tmp_path / name

    layout = h5py.VirtualLayout(shape=(n, 3), dtype="f8")
    layout[:] = h5py.VirtualSource(str(tmp_path / "target.h5"), "rgb", shape=(n, 3))
    for name, values, says in (
            ("file.h5", lambda f: f.create_dataset("rgb", (n, 3), "f8", external=[(
                str(tmp_path / "secret.bin"), 0, n * 24)]), "keeps its values in other files"),
            ("fifo.h5", lambda f: f.create_dataset("rgb", (n, 3), "f8", external=[(
                str(tmp_path / "fifo"), 0, n * 24)]), "keeps its values in other files"),
            ("virtual.h5", lambda f: f.create_virtual_dataset("rgb", layout),
             "keeps its values in other files"),
            ("link.h5", lambda f: f.__setitem__("rgb", h5py.ExternalLink(
                str(tmp_path / "target.h5"), "rgb")), "rgb is an external link"),
            ("angle.h5", lambda f: (f.__delitem__("theta_i"), f.__setitem__(
                "theta_i", h5py.ExternalLink(str(tmp_path / "target.h5"), "rgb")),
                f.__setitem__("rgb", np.full((n, 3), 0.2))), "theta_i is an external link"),
            ("loop.h5", lambda f: f.__setitem__("rgb", h5py.SoftLink("/rgb")),
             "rgb is a link to an object that cannot be opened")):
        with pytest.raises(MeasurementsError, match=says):
            read_measured(listed(name, values))


def test_a_long_layout_is_pivoted_to_the_wide_files_samples(tmp_path):
    """One row per (direction pair, channel), as pandas' melt writes it and a spectral
    gonioreflectometer exports a run: read as the wide file of the same samples (it was
    refused; before stop 74, fitted as grey samples). Each pair must give each channel
    once, a row that lacks one or gives one twice is named; a polarisation column is
    refused, not averaged."""
    from brdffit.io.readers import input_summary

    s = _samples(40)
    wide = read_measured(_write_all(tmp_path, s)["csv"])
    deg = [np.degrees(a) for a in s[:4]]
    head = "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg"

    def long(name, column, cells, values, order=None, sep=","):
        rows = [f"{deg[0][k]},{deg[1][k]},{deg[2][k]},{deg[3][k]},{c},{float(values[k, j])!r}"
                for k in range(40) for j, c in enumerate(cells)]
        rows = rows if order is None else [rows[i] for i in order]
        path = tmp_path / name
        path.write_text(f"{head},{column},value\n".replace(",", sep)
                        + "".join(r.replace(",", sep) + "\n" for r in rows))
        return path

    # R, G, B in any words, rows in any order: the wide file's samples exactly (in the
    # order their pairs first appear)
    def samples(m):
        return np.unique(np.column_stack([m.wi, m.wo, m.rgb]), axis=0)

    shuffled = np.random.default_rng(1).permutation(120)
    for cells, order in (("rgb", None), (("Red", "Green", "Blue"), shuffled)):
        m = read_measured(long("rgb.csv", "channel", cells, s[4], order))
        assert m.n == 40
        np.testing.assert_array_equal(samples(m), samples(wide))
        assert input_summary(m)["long_layout"] == {"rows": 120, "column": "channel",
                                                   "per_sample": "r, g, b"}
    np.testing.assert_array_equal(m.wi[0], wide.wi[shuffled[0] // 3])
    # semicolons and decimal commas, as a spreadsheet of such a locale exports it
    text = long("rgb.csv", "channel", "rgb", s[4]).read_text()
    comma = tmp_path / "comma.csv"
    comma.write_text(text.replace(",", ";").replace(".", ","))
    np.testing.assert_allclose(read_measured(comma).rgb, wide.rgb, rtol=1e-12)
    # spectra: by a wavelength column in nm, or by a channel column of 450nm cells, or
    # in an ASTM file: projected as the wide file's spectral columns are
    lam = np.arange(380.0, 781.0, 20.0)
    spectra = np.outer(s[4][:, 0], np.ones(lam.size)) + np.outer(s[4][:, 2], lam / 780.0)
    wide_spectral = tmp_path / "wide_spectral.csv"
    wide_spectral.write_text(f"{head}," + ",".join(f"{x:g}nm" for x in lam) + "\n" + "".join(
        ",".join(repr(float(x)) for x in (*(d[k] for d in deg), *spectra[k])) + "\n"
        for k in range(40)))
    expected = read_measured(wide_spectral)
    for path in (long("nm.csv", "wavelength [nm]", [f"{x:g}" for x in lam], spectra),
                 long("band.csv", "band", [f"{x:g}nm" for x in lam], spectra)):
        m = read_measured(path)
        np.testing.assert_allclose(m.rgb, expected.rgb, rtol=1e-14)  # one matrix product
        assert m.provenance["spectral"]["wavelengths_nm"] == [380.0, 780.0, lam.size]
    for cells, said in (([f"{x / 1000:g}" for x in lam], "holds wavelengths up to 0.78: "
                                                           "micrometres. Write them in nm"),
                        ([f"{x - 400:g}" for x in lam], "holds a wavelength of -20 nm")):
        with pytest.raises(MeasurementsError, match=said):
            read_measured(long("odd_nm.csv", "wavelength", cells, spectra))
    astm = tmp_path / "long.astm"
    astm.write_text("VARS theta_i,phi_i,theta_s,phi_s,channel,BRDF\n" + "".join(
        ",".join(repr(float(a[k])) for a in s[:4]) + f",{c},{float(s[4][k, j])!r}\n"
        for k in range(40) for j, c in enumerate("rgb")))
    np.testing.assert_allclose(read_measured(astm).rgb, wide.rgb, rtol=1e-15)
    # the channel first: its rows were read as header keys ("no data")
    astm.write_text("VARS channel,theta_i,phi_i,theta_s,phi_s,BRDF\n" + "".join(
        f"{c}," + ",".join(repr(float(a[k])) for a in s[:4]) + f",{float(s[4][k, j])!r}\n"
        for k in range(40) for j, c in enumerate("rgb")))
    np.testing.assert_allclose(read_measured(astm).rgb, wide.rgb, rtol=1e-15)
    # a channel or wavelength column is known by a word of its name (under a name
    # outside a short list its rows were read as grey samples of repeated directions),
    # a units row may say nm
    for column in ("rgb_channel", "Channel_ID", "ch"):
        np.testing.assert_array_equal(samples(read_measured(long("named.csv", column, "rgb",
                                                                 s[4]))), samples(wide))
    for column in ("WL_nm", "wave_length", "lambda (nm)"):
        m = read_measured(long("nm2.csv", column, [f"{x:g}" for x in lam], spectra))
        np.testing.assert_allclose(m.rgb, expected.rgb, rtol=1e-14)
    units_row = long("units.csv", "wavelength", [f"{x:g}" for x in lam], spectra).read_text()
    units_row = units_row.replace("\n", "\n,,,,nm,\n", 1)
    (tmp_path / "units.csv").write_text(units_row)
    np.testing.assert_allclose(read_measured(tmp_path / "units.csv").rgb, expected.rgb,
                               rtol=1e-14)
    # what cannot be pivoted is named, with its row
    lines = long("rgb.csv", "channel", "rgb", s[4]).read_text().splitlines()
    for name, rows, said in (
            ("missing.csv", lines[:5] + lines[6:], "the direction pair of row 5 has no row "
                                                   "for channel g .2 of the 3"),
            # one channel's angles written with other digits: the near row is named
            ("digits.csv", [lines[0], lines[1], ",".join(
                f"{float(c) + 1e-5!r}" if i == 2 else c
                for i, c in enumerate(lines[2].split(","))), *lines[3:]],
             "the direction pair of row 2 has no row for channel g .2 of the 3.*; row 3 "
             "gives it at angles within 1e-05 degrees of these .theta_o_deg "
             f"{float(deg[2][0]) + 1e-5!r} there.: the same direction written with other "
             "digits"),
            ("twice.csv", [*lines, lines[3]], "rows 4 and 122 both give channel b of one "
                                              "direction pair: keep one"),
            ("green.csv", [lines[0], *(r for r in lines if r.endswith(tuple(
                f",g,{float(s[4][k, 1])!r}" for k in range(40))))],
             "names channel.s. g alone: every direction needs a row for each of r, g, b; if "
             "every row holds the same channel, drop the column"),
            ("odd.csv", [lines[0], lines[1].replace(",r,", ",IR,"), *lines[2:]],
             "row 2: column 'channel' holds 'IR', which names no channel"),
            ("mixed.csv", [lines[0], lines[1].replace(",r,", ",450nm,"), *lines[2:]],
             "names both RGB channels and wavelengths"),
            ("wide_too.csv", [lines[0].replace("value", "r,g,b")]
             + [r + ",1,1" for r in lines[1:]],
             "each row's value is then one column, value .also brdf, y.; the file's value "
             "columns: r, g, b"),
            ("two.csv", [lines[0].replace("channel", "channel,wavelength")]
             + [r.replace(",r,", ",r,1,").replace(",g,", ",g,1,").replace(",b,", ",b,1,")
                for r in lines[1:]], "columns 'channel' and 'wavelength' both say"),
            ("polarised.csv", [lines[0].replace("channel", "polarization"), *lines[1:]],
             "column 'polarization' says which polarisation each row holds: a "
             "polarisation-resolved list is not read"),
            # each row checked as a wide file's sample is, named by its own row (the
            # pair's first row after the pivot was named, and a channel's sigma_g)
            ("nan.csv", [lines[0], lines[1], "nan" + lines[2][lines[2].index(","):],
                         *lines[3:]], "theta_i_deg is not finite in 1 row .first: row 3."),
            ("micrometres.csv", [lines[0].replace("channel", "wavelength [um]"), *lines[1:]],
             "column 'wavelength .um.' gives wavelengths in 'um': write them in nm")):
        (tmp_path / name).write_text("\n".join(rows) + "\n")
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / name)


def test_a_long_layout_of_named_arrays_is_pivoted_as_a_csvs_is(tmp_path):
    """HDF5 datasets, .npz arrays and MATLAB variables of one row per (direction pair,
    channel): the channel as text (h5py's strings, numpy's, a MATLAB char column or cell
    of strings, a -v7.3 char matrix) or wavelengths in nm; read as the wide file's
    samples. A text channel was left out of an .npz or .mat file unread, and its rows
    fitted as grey samples without a word."""
    from scipy import io

    s = _samples(30)
    wide = read_measured(_write_all(tmp_path, s)["hdf5"])
    deg = {f"{a}_deg": np.repeat(np.degrees(x), 3) for a, x in zip(
        ("theta_i", "phi_i", "theta_o", "phi_o"), s[:4], strict=True)}
    channel = np.array(list("rgb" * 30))
    long = {**deg, "value": s[4].ravel(), "channel": channel}
    np.savez(tmp_path / "long.npz", **long)
    io.savemat(tmp_path / "char.mat", long)  # a char column, channel = ['r'; 'g'; ...]
    io.savemat(tmp_path / "cell.mat", {**long, "channel": np.array([[c] for c in channel],
                                                                    dtype=object)})
    with h5py.File(tmp_path / "long.h5", "w") as f:
        for k, a in long.items():
            f[k] = np.array(["Red", "Green", "Blue"] * 30, dtype=object) if k == "channel" else a
    with h5py.File(tmp_path / "v73.mat", "w", userblock_size=512) as f:  # save -v7.3's way
        for k, a in long.items():
            stored = np.array([[ord(c)] for c in a], np.uint16).T if k == "channel" else a[None]
            f.create_dataset(k, data=stored).attrs["MATLAB_class"] = np.bytes_(
                "char" if k == "channel" else "double")
    with open(tmp_path / "v73.mat", "r+b") as raw:
        raw.write(b"MATLAB 7.3 MAT-file")
    for name in ("long.npz", "char.mat", "cell.mat", "long.h5", "v73.mat"):
        m = read_measured(tmp_path / name)
        np.testing.assert_array_equal(m.rgb, wide.rgb, err_msg=name)
        np.testing.assert_allclose(m.wi, wide.wi, rtol=0, atol=1e-15, err_msg=name)
        assert m.provenance["long_layout"] == {"rows": 90, "column": "channel",
                                               "per_sample": "r, g, b"}, name
    # a spectrum by wavelength, the wavelengths beside no spectral array
    lam = np.arange(400.0, 701.0, 50.0)
    spectra = np.outer(s[4][:, 1], np.linspace(0.5, 1.5, lam.size))
    np.savez(tmp_path / "wide_spectral.npz", **{k: a[::3] for k, a in deg.items()},
             spectral=spectra, wavelengths=lam)
    np.savez(tmp_path / "long_spectral.npz", **{k: np.repeat(a[::3], lam.size)
                                                for k, a in deg.items()},
             brdf=spectra.ravel(), wavelengths=np.tile(lam, 30))
    np.testing.assert_allclose(read_measured(tmp_path / "long_spectral.npz").rgb,
                               read_measured(tmp_path / "wide_spectral.npz").rgb, rtol=1e-14)
    # wide files' metadata of those names are not read (one element, or not one per row)
    wide_arrays = {k: a[::3] for k, a in deg.items()}
    for note in ({"lambda": 0.1, "color": "red", "filter": {"type": "ND"}},
                 {"wavelengths": np.array([[610.0, 550.0, 465.0]])}):
        io.savemat(tmp_path / "wide.mat", {**wide_arrays, "rgb": s[4], **note})
        np.testing.assert_array_equal(read_measured(tmp_path / "wide.mat").rgb, wide.rgb)
    for change, said in (
            ({"channel": channel[:-1]}, "array channel holds 89 value.s., not one per row .90."),
            ({"channel": np.array(list(channel[:-1]) + ["x"] * 3)},
             "array channel holds 92 value.s., not one per row"),
            ({"channel": np.zeros(0)}, "array channel holds 0 value.s."),
            ({"channel": channel.reshape(30, 3)}, "array channel has shape .30, 3.: expected "
                                                  ".n,., one per row"),
            ({"Channel": channel}, "arrays '.hannel' and '.hannel' both say"),
            ({"sigma": np.full(91, 0.1)}, "sigma has shape .91,.: expected .90,."),
            ({"theta_i_deg": deg["theta_i_deg"][:-3]}, "90 values but angles of .87, 90, 90, "
                                                       "90. rows"),
            ({"channel": np.array([b"r", b"g", b"b"] * 30)}, None),  # bytes: decoded
            ({"channel": np.array(["r", "g", "b\x00x"] * 30)}, "row 3: array 'channel' holds "
                                                              "'b.{1,2}x00x'"),
            ({"channel": np.array(["r" * 5000] * 90)}, "holds texts of 20,000 bytes each"),
            ({"channel": np.array(["IR"] * 90)}, "row 1: array 'channel' holds 'IR', which "
                                                 "names no channel"),
            ({"polarization": np.ones(90)}, "array 'polarization' says which polarisation "
                                            "each row holds: a polarisation-resolved list is "
                                            "not read"),
            ({"wavelength": np.ones(90)}, "arrays 'channel' and 'wavelength' both say")):
        np.savez(tmp_path / "bad.npz", **{**long, **change})
        if said is None:
            np.testing.assert_array_equal(read_measured(tmp_path / "bad.npz").rgb, wide.rgb)
            continue
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / "bad.npz")
    # MATLAB: a 1 x n char is one text; a cell with an empty text names its row
    cell = np.array([[c] for c in channel], dtype=object)
    cell[4, 0] = ""
    for name, variable, said in (
            ("row.mat", "".join(channel), "variable channel holds 1 value.s., not one per row "
                                          ".90.: .*a char row vector is one text: save a "
                                          "column, channel.:."),
            ("empty_cell.mat", cell, "row 5: variable 'channel' holds ''")):
        io.savemat(tmp_path / name, {**long, "channel": variable})
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / name)
    # HDF5: text that is not UTF-8, references (MATLAB -v7.3's cell), a null dataspace
    for name, make, said in (
            ("latin.h5", lambda f: f.create_dataset("channel", data=np.array(
                [b"r", b"\xff", b"b"] * 30)), "dataset channel holds text that is not UTF-8"),
            ("refs.h5", lambda f: f.create_dataset("channel", shape=(90,),
                                                   dtype=h5py.ref_dtype),
             "dataset channel holds neither text nor numbers"),
            ("null.h5", lambda f: f.create_dataset("channel", data=h5py.Empty("S1")),
             "dataset channel holds 0 value.s., not one per row .90.")):
        with h5py.File(tmp_path / name, "w") as f:
            for k, a in long.items():
                if k != "channel":
                    f[k] = a
            make(f)
        with pytest.raises(MeasurementsError, match=said):
            read_measured(tmp_path / name)


def test_an_excel_sheet_is_read_as_the_csv_it_would_be_saved_as(tmp_path, monkeypatch):
    """An .xlsx workbook (it was refused: "save the sheet as CSV"): its first sheet with
    a cell, every digit of its numbers, a row index, a units row, numbers Excel holds as
    text with a decimal comma, a long layout; a workbook by content whatever its name;
    one that expands too far, an .xls, a formula without a value: one line each."""
    import openpyxl

    from brdffit.io import workbook
    from brdffit.io.readers import input_summary

    s = _samples(30)
    wide = read_measured(_write_all(tmp_path, s)["csv"])
    head = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    rows = [[float(x) for x in (*(np.degrees(a[k]) for a in s[:4]), *s[4][k])]
            for k in range(30)]

    def book(name, sheet_rows, first_sheet=None):
        wb = openpyxl.Workbook()
        wb.active.title = "Messung"
        for row in sheet_rows:
            wb.active.append(row)
        if first_sheet is not None:
            wb.create_sheet(first_sheet, 0)  # an empty sheet before it
        wb.save(tmp_path / name)
        return tmp_path / name

    for name, sheet_rows, first in (
            ("plain.xlsx", [head, *rows], None),
            ("noted.xlsx", [["# gonio run 12", None, "2024-05-05"], head, *rows], "Notes"),
            ("index.xlsx", [[None, *head], *([k, *r] for k, r in enumerate(rows))], None),
            ("units.xlsx", [[h.removesuffix("_deg") for h in head], ["deg"] * 4 + ["1/sr"] * 3,
                            *rows], None),
            ("text.xlsx", [head, *([repr(x).replace(".", ",") for x in r] for r in rows)],
             None)):
        m = read_measured(book(name, sheet_rows, first))
        np.testing.assert_allclose(m.rgb, wide.rgb, rtol=1e-15, err_msg=name)
        np.testing.assert_allclose(m.wi, wide.wi, rtol=0, atol=1e-15, err_msg=name)
        summary = input_summary(m)
        assert (summary["format"], summary["sheet"]) == ("xlsx", "Messung"), name
        assert summary["sheets"] == (1 if first is None else 2), name
        assert summary.get("decimal_comma", False) == (name == "text.xlsx"), name
    long = book("long.xlsx", [[*head[:4], "channel", "value"], *(
        [*r[:4], c, r[4 + j]] for r in rows for j, c in enumerate("RGB"))])
    np.testing.assert_allclose(read_measured(long).rgb, wide.rgb, rtol=1e-15)
    for other in ("workbook.csv", "workbook"):  # by content, whatever its name
        (tmp_path / other).write_bytes((tmp_path / "plain.xlsx").read_bytes())
        assert read_measured(tmp_path / other).provenance["format"] == "xlsx"
    # refused, one line each
    (tmp_path / "old.xls").write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(600))
    formula = openpyxl.Workbook()
    formula.active.append(head)
    formula.active.append([*rows[0][:6], "=E1*2"])  # openpyxl computes no value
    formula.save(tmp_path / "formula.xlsx")
    import zipfile

    with zipfile.ZipFile(tmp_path / "archive.xlsx", "w") as z:  # a zip of no workbook
        z.writestr("notes.txt", "nothing")
    for name, said in (("old.xls", "an OLE2 document .an Excel 97-2003 .xls workbook\\? save "
                                   "it as .xlsx or CSV."),
                       ("formula.xlsx", "row 2 has 6 values, the header names 7 columns; "
                                        "cell G2 .=E1\\*2. holds a formula whose value was "
                                        "never computed"),
                       ("archive.xlsx", "not a readable Excel workbook")):
        with pytest.raises(MerlFormatError, match=said):  # MeasurementsError is one
            read_measured(tmp_path / name)
    monkeypatch.setattr(workbook, "MAX_EXPANDED", 10_000)
    with pytest.raises(MeasurementsError, match="an Excel workbook whose parts expand to "
                                                "[0-9,]+ bytes: more than a sample list's"):
        read_measured(tmp_path / "plain.xlsx")



def test_merged_header_cells_are_read_as_the_header_they_show(tmp_path):
    """A lab's sheet with merged cells in its header (they read "line 1 is read as the
    header" or "no column for theta_i"; openpyxl's read-only sheets give a range's
    value in its first cell alone): a title across the columns, groups over their
    columns' names, names merged down two rows. Each reads as the plain sheet; a bad
    row keeps its own number; merged cells among the numbers are left as they are."""
    import openpyxl

    s = _samples(30)
    wide = read_measured(_write_all(tmp_path, s)["csv"])
    rows = [[float(x) for x in (*(np.degrees(a[k]) for a in s[:4]), *s[4][k])]
            for k in range(30)]

    def book(name, head_rows, merged, body=rows):
        wb = openpyxl.Workbook()
        for row in [*head_rows, *body]:
            wb.active.append(row)
        for ref in merged:
            wb.active.merge_cells(ref)
        wb.save(tmp_path / name)
        return tmp_path / name

    names = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    title = book("title.xlsx", [["Gonioreflectometer run 12, sample A"], names], ["A1:G1"])
    groups = book("groups.xlsx", [
        ["Incident (deg)", None, "Outgoing (deg)", None, "BRDF (1/sr)", None, None],
        ["theta", "phi", "theta", "phi", "R", "G", "B"]], ["A1:B1", "C1:D1", "E1:G1"])
    down = book("down.xlsx", [
        ["theta_i (deg)", "phi_i (deg)", "theta_o (deg)", "phi_o (deg)", "BRDF", None, None],
        [None, None, None, None, "red", "green", "blue"]],
        ["A1:A2", "B1:B2", "C1:C2", "D1:D2", "E1:G1"])
    both = book("both.xlsx", [["Run 12"], *[[c for c in r] for r in (
        ["Incident (deg)", None, "Outgoing (deg)", None, "BRDF", None, None],
        ["theta", "phi", "theta", "phi", "R", "G", "B"])]],
        ["A1:G1", "A2:B2", "C2:D2", "E2:G2"])
    for path in (title, groups, down, both):
        m = read_measured(path)
        np.testing.assert_allclose(m.rgb, wide.rgb, rtol=1e-15, err_msg=path.name)
        np.testing.assert_allclose(m.wi, wide.wi, rtol=0, atol=1e-15, err_msg=path.name)
    # a bad row is named by its row in the sheet, as in a sheet of no merged cells
    bad = [list(r) for r in rows]
    bad[4][2] = "n/a"
    with pytest.raises(MeasurementsError, match=r"\b(row|line) 7\b"):
        read_measured(book("bad.xlsx", [
            ["Incident (deg)", None, "Outgoing (deg)", None, "BRDF", None, None],
            ["theta", "phi", "theta", "phi", "R", "G", "B"]], ["A1:B1", "C1:D1", "E1:G1"],
            body=bad))
    # merged among the numbers: no header of them (the row is read, and refused, as is)
    with pytest.raises(MeasurementsError, match=r"\b(row|line) 3\b"):
        read_measured(book("body.xlsx", [names], ["E3:G3"]))
    # a sample's name merged down its rows (a column not read): read as without the merge
    named = book("named.xlsx", [["sample", *names]], ["A2:A11"],
                 body=[["S1" if k == 0 else None, *r] for k, r in enumerate(rows)])
    np.testing.assert_allclose(read_measured(named).rgb, wide.rgb, rtol=1e-15)
    # a group over some columns alone is a group, not a title; a units row under the
    # header stays the units row
    lone = book("lone.xlsx", [["Incident", None, None, None, None, None, None],
                              ["theta", "phi", "theta_o", "phi_o", "r", "g", "b"],
                              ["deg", "deg", "deg", "deg", "1/sr", "1/sr", "1/sr"]], ["A1:B1"])
    m = read_measured(lone)
    np.testing.assert_allclose(m.wi, wide.wi, rtol=0, atol=1e-15)


def test_a_hidden_sheet_is_read_after_the_visible_ones_and_said(tmp_path):
    """A hidden sheet before the one on show was fitted instead of it (a review's
    workbook: 100 hidden rows fitted, 500 shown ones not), said only by its name."""
    import openpyxl

    from brdffit.io.readers import input_summary

    head = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    s = _samples(40)
    wb = openpyxl.Workbook()
    wb.active.title = "old run"
    wb.active.sheet_state = "hidden"
    shown = wb.create_sheet("run 2")
    for sheet, scale in ((wb["old run"], 2.0), (shown, 1.0)):
        sheet.append(head)
        for k in range(40):
            sheet.append([float(x) for x in (*(np.degrees(a[k]) for a in s[:4]),
                                               *(scale * s[4][k]))])
    book = tmp_path / "hidden.xlsx"
    wb.save(book)
    m = read_measured(book)
    assert m.provenance["sheet"] == "run 2" and "sheet_hidden" not in m.provenance
    np.testing.assert_allclose(m.rgb, s[4], rtol=1e-12)
    named = read_measured(book, sheet="old run")
    assert named.provenance["sheet_hidden"] is True
    assert input_summary(named)["sheet_hidden"] is True


def test_a_workbook_sheet_is_fitted_by_its_name(tmp_path):
    """A workbook of two sheets of samples fitted the first, and the second could not be
    reached. ``sheet=`` (``brdffit fit --sheet``) reads the one named; a name the
    workbook lacks is refused with its sheets' names, as is a sheet named for a file
    with no sheets; an export re-reads the sheet that was fitted, not the first."""
    import openpyxl

    from brdffit.export import export
    from brdffit.fitting.result import FitResult
    from tests.cli_helpers import run_main

    head = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    s = _samples(40)

    def rows(scale):
        return [[float(x) for x in (*(np.degrees(a[k]) for a in s[:4]), *(scale * s[4][k]))]
                for k in range(40)]

    wb = openpyxl.Workbook()
    wb.active.title = "sample A"
    for row in [head, *rows(1.0)]:
        wb.active.append(row)
    second = wb.create_sheet("sample B")
    for row in [head, *rows(3.0)]:
        second.append(row)
    wb.create_sheet("empty")
    bad = wb.create_sheet("bad")
    for row in [head, ["n/a"] * 7]:
        bad.append(row)
    book = tmp_path / "two.xlsx"
    wb.save(book)
    first, named = read_measured(book), read_measured(book, sheet="sample B")
    assert first.provenance["sheet"] == "sample A" and named.provenance["sheet"] == "sample B"
    np.testing.assert_allclose(named.rgb, 3.0 * first.rgb, rtol=1e-12)
    assert read_table(book, sheet="sample B")[1]["sheet"] == "sample B"
    for sheet, said in (("sample C", "no sheet named 'sample C': the workbook's sheets are "
                                     "'sample A', 'sample B', 'empty', 'bad'"),
                        ("empty", "sheet 'empty' holds no cells"),
                        ("bad", "sheet 'bad': ")):
        with pytest.raises(MeasurementsError, match=re.escape(said)):
            read_measured(book, sheet=sheet)
    csv = _write_all(tmp_path, s)["csv"]
    with pytest.raises(MeasurementsError, match="a sheet was named .'sample B'., and this is "
                                                "no Excel workbook"):
        read_measured(csv, sheet="sample B")

    out = run_main("brdffit.cli", "fit", str(book), "--sheet", "sample B", "--model",
                   "lambert", "--json")
    assert out.returncode == 0, out.stderr
    fitted = json.loads(out.stdout)
    assert fitted["input"]["sheet"] == "sample B"
    # re-read from its own file: the sheet fitted, or the fidelity would be to sample A
    # (3x darker) under a warning that the file changed since the fit
    got = export(FitResult.from_dict(fitted), "gltf")
    assert not [w for w in got.warnings if "does not hold" in w], got.warnings
    assert got.fidelity.get("log_rmse_to_table") is not None
    out = run_main("brdffit.cli", "fit", str(book), "--sheet", "nope", "--model", "lambert")
    assert out.returncode != 0 and "no sheet named 'nope'" in out.stderr
    assert "Traceback" not in out.stderr


def test_a_workbook_that_opens_on_a_sheet_of_notes_is_read_from_its_samples(tmp_path):
    """A lab's workbook often opens on a sheet of notes, or a chart's data: the first
    sheet that reads as samples is read, and the result names each sheet passed over
    and why. Where no sheet reads, the refusal gives each sheet's reason."""
    import openpyxl

    from brdffit.io.readers import input_summary
    from tests.cli_helpers import run_main

    s = _samples(20)
    wide = read_measured(_write_all(tmp_path, s)["csv"])
    head = ["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"]
    rows = [[float(x) for x in (*(np.degrees(a[k]) for a in s[:4]), *s[4][k])]
            for k in range(20)]
    wb = openpyxl.Workbook()
    wb.active.title = "About"
    wb.active.append(["Gonioreflectometer run 12, sample 7"])
    wb.active.append(["operator", "J. Doe"])
    wb.create_sheet("empty")
    chart = wb.create_sheet("chart")
    chart.append(["x", "y"])
    chart.append([1, 2])
    data = wb.create_sheet("Messung")
    for row in [head, *rows]:
        data.append(row)
    wb.create_sheet("more")["A1"] = "left alone: after the sheet read"
    wb.save(tmp_path / "lab.xlsx")
    m = read_measured(tmp_path / "lab.xlsx")
    np.testing.assert_allclose(m.rgb, wide.rgb, rtol=1e-15)
    summary = input_summary(m)
    assert (summary["sheet"], summary["sheets"]) == ("Messung", 5)
    assert [p["sheet"] for p in summary["sheets_passed"]] == ["About", "chart"]
    assert "no column for theta_i" in summary["sheets_passed"][1]["why"]
    out = run_main("brdffit.cli", "fit", str(tmp_path / "lab.xlsx"), "--model", "lambert")
    assert out.returncode == 0, out.stderr
    assert "sheet 'Messung' of 5; sheet 'About' passed over: no column" in out.stderr
    # as the service stores an upload (HDF5): what it was, read back
    from brdffit.io.writers import write_hdf5

    theta_i, phi_i, theta_o, phi_o, rgb = s
    np.savez(tmp_path / "s.npz", theta_i_rad=theta_i, phi_i_rad=phi_i, theta_o_rad=theta_o,
             phi_o_rad=phi_o, rgb=rgb)
    for read in (m, read_measured(tmp_path / "s.npz")):
        stored = read_measured(write_hdf5(read, tmp_path / "stored.h5"))
        # the format it was read in, its sheet and the sheets passed over: kept (it read
        # "hdf5", and the sheet was lost)
        assert input_summary(stored) == input_summary(read)
        assert stored.provenance["stored_as"] == "hdf5"
    # a lab's own JSON under that attribute name is not brdffit's: read as what it is
    import h5py

    for foreign in ({"format": "xlsx", "sheets": "3"}, {"format": "csv", "sheets": 2},
                    {"format": "xlsx", "sheet": "a", "sheets": 3, "sheets_passed": ["x"]},
                    {"format": "csv", "long_layout": {"rows": "9"}}):
        with h5py.File(tmp_path / "stored.h5", "a") as f:
            f.attrs["provenance"] = json.dumps(foreign)
        assert read_measured(tmp_path / "stored.h5").provenance["format"] == "hdf5"
        out = run_main("brdffit.cli", "fit", str(tmp_path / "stored.h5"), "--model", "lambert")
        assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    # the samples' sheet with a bad row is refused, not passed over for the next sheet
    bad = openpyxl.Workbook()
    bad.active.title = "Messung"
    for k, row in enumerate([head, *rows]):
        bad.active.append(["n/a", *row[1:]] if k == 5 else row)
    copy = bad.create_sheet("copy")
    for row in [head, *rows]:
        copy.append(row)
    bad.save(tmp_path / "bad.xlsx")
    with pytest.raises(MeasurementsError, match="sheet 'Messung': row 6"):
        read_measured(tmp_path / "bad.xlsx")
    del wb["Messung"]
    wb.save(tmp_path / "notes.xlsx")
    with pytest.raises(MeasurementsError, match="sheet 'About': no column for theta_i.*; "
                                                "sheet 'chart': no column for theta_i.*x, y"):
        read_measured(tmp_path / "notes.xlsx")

def test_a_scale_factor_of_zero_is_refused_by_name(tmp_path):
    s = _samples(20)
    path = tmp_path / "zero.h5"
    with h5py.File(path, "w") as f:
        for a, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), s[:4], strict=True):
            f.create_dataset(a, data=np.degrees(v)).attrs["units"] = "degrees"
        f.create_dataset("rgb", data=s[4]).attrs["scale_factor"] = 0.0
    with pytest.raises(MeasurementsError, match="scale_factor 0 makes every value 0"):
        read_measured(path)


@pytest.mark.parametrize("key, mark, packed", [("missing_value", 999.0, False),
                                                ("_FillValue", -9999.0, False),
                                                ("_FillValue", 65535, True)])
def test_an_hdf5_value_marked_not_measured_is_refused_by_its_mark(tmp_path, key, mark, packed):
    """CF's _FillValue and missing_value: 37 rows of 999 marked missing were fitted as data
    (kd 3.1 for 0.2, "successful"), and -9999 was refused as a negative value. Refused
    by the mark's name, as a CSV's "n/a" cell is; a mark no value holds reads as before."""
    s = _samples(60)
    deg = [np.degrees(a) for a in s[:4]]
    path = tmp_path / "marked.h5"
    values = np.round(s[4] / 1e-4).astype(np.uint16) if packed else s[4].copy()
    with h5py.File(path, "w") as f:
        for a, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), deg, strict=True):
            f.create_dataset(a, data=v).attrs["units"] = "degrees"
        clean = f.create_dataset("rgb", data=values)
        if packed:
            clean.attrs["scale_factor"] = 1e-4
        clean.attrs[key] = mark
    read_measured(path)  # no value holds the mark
    with h5py.File(path, "r+") as f:
        f["rgb"][4] = mark
    with pytest.raises(MeasurementsError, match=re.escape(
            f"dataset rgb: 3 values are its {key} ({mark:g}), the mark of a value not "
            "measured: leave those samples out of the file before fitting")):
        read_measured(path)


def test_radiances_beside_their_irradiance_are_refused_saying_what_a_brdf_is(tmp_path):
    """A review's "value,irradiance" file was fitted as a BRDF (kd 3.5, the irradiance
    never read); "radiance,irradiance" was "no value columns". Both say what to divide;
    a BRDF column beside a lamp's record reads as before."""
    head = "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,"
    rows = "".join(f"{10 + k},0,{20 + k},180,0.4,10\n" for k in range(20))
    for columns in ("value,irradiance", "radiance,irradiance", "r,E_i"):
        path = tmp_path / "radiance.csv"
        path.write_text(head + columns + "\n" + rows.replace(",0.4,10", ",0.4,10"))
        with pytest.raises(MeasurementsError, match="holds the light falling on the sample: "
                           r"are the values radiances\? brdffit reads a BRDF, in 1/sr"):
            read_measured(path)
    alone = tmp_path / "alone.csv"
    alone.write_text(head + "radiance\n" + "".join(f"{10 + k},0,{20 + k},180,0.4\n"
                                                   for k in range(20)))
    with pytest.raises(MeasurementsError, match="no value columns.*'radiance': a radiance, "
                                                "not a BRDF"):
        read_measured(alone)
    kept = tmp_path / "kept.csv"
    kept.write_text(head + "brdf,lamp_power\n" + rows)
    assert read_measured(kept).rgb.shape == (20, 3)


def test_files_as_lab_tools_write_them(tmp_path):
    """What a review of files written by other tools found (/tmp/h32d in session 32): a
    long layout (one row per direction and channel) was fitted as grey samples without
    a word; an HDF5 rgb in percent was fitted as 1/sr and one packed as CF's uint16 with
    scale_factor as kd 4000; a date in a column not read had a German export refused;
    a Cornell ASTM header's second COMMENT was refused; pandas' and R's row index
    column was refused as a column without a name."""
    s = _samples(60)
    plain = read_measured(_write_all(tmp_path, s)["csv"])
    deg = [np.degrees(a) for a in s[:4]]
    # one row per (direction, channel): read as the wide file (test_a_long_layout_...)
    long = tmp_path / "long.csv"
    long.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,channel,value\n" + "".join(
        f"{deg[0][k]},{deg[1][k]},{deg[2][k]},{deg[3][k]},{c},{s[4][k, j]}\n"
        for k in range(60) for j, c in enumerate("RGB")))
    np.testing.assert_array_equal(read_measured(long).rgb, plain.rgb)
    # an uncertainty by another name than sigma_r: refused, saying what to name it (the
    # fit weighed every sample alike, without a word)
    for header, said in (("r,g,b,r_std,g_std,b_std", "r_std"),
                         ("R,G,B,R_err,G_err,B_err", "R_err"), ("value,uncertainty", "uncertainty"),
                         ("r,g,b,sigma_red,sigma_green,sigma_blue", "sigma_red"),
                         ("Red,Green,Blue,Std Red", "Std Red"),
                         ("r,g,b,stderr_r,stderr_g,stderr_b", "stderr_r"),
                         ("r,g,b,r_sem", "r_sem"), ("value,variance", "variance"),
                         ("value,ci95", "ci95")):
        odd = tmp_path / "odd.csv"
        width = header.count(",") + 1
        odd.write_text(f"theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,{header}\n"
                       + "10,0,20,180," + ",".join(["0.5"] * width) + "\n")
        with pytest.raises(MeasurementsError, match=f"column {said!r} looks like each value's "
                                                    "uncertainty.*Rename it so"):
            read_measured(odd)
    # a title above the header, and a units row in arbitrary units: said as such (the
    # title's words were named as the columns, the angles called unitless)
    titled = tmp_path / "titled.csv"
    titled.write_text("Gonio run 12, 2024-05-05\n"
                      "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,20,180,1,1,1\n")
    with pytest.raises(MeasurementsError, match="line 1 .'Gonio run 12, 2024-05-05'. is read "
                                                "as the header, and line 2 names the columns"):
        read_measured(titled)
    au = tmp_path / "au.csv"
    au.write_text("theta_i,phi_i,theta_o,phi_o,r,g,b\ndeg,deg,deg,deg,a.u.,a.u.,a.u.\n"
                  "10,0,20,180,1,1,1\n")
    with pytest.raises(MeasurementsError, match=r"no value columns.*'r \[a.u.\]', 'g \[a.u.\]'"
                                                r", 'b \[a.u.\]': a unit that is not 1/sr"):
        read_measured(au)
    # a reflectance factor's units row (1, BRF, reflectance): the values refused as not
    # a BRDF, saying what a BRF is (it read as no units row, and the angles were called
    # unitless); a first data row of ones is still a data row
    for unit in ("1", "BRF", "reflectance", "[reflectance factor]"):
        au.write_text(f"theta_i,phi_i,theta_o,phi_o,r,g,b\ndeg,deg,deg,deg,{unit},{unit},"
                      f"{unit}\n10,0,20,180,1,1,1\n")
        with pytest.raises(MeasurementsError, match=r"'b \[.*\]': a unit that is not 1/sr.*"
                                                    r"a reflectance factor \(BRF\) is pi times "
                                                    r"the BRDF: divide the values by pi"):
            read_measured(au)
    au.write_text("theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n1,1,1,1,1,1,1\n"
                  "10,0,20,180,1,1,1\n")
    assert len(read_measured(au).rgb) == 2
    # a units row in a radiance's units: refused as radiances (it read as no units row,
    # and the angles were called unitless)
    for unit in ("W/(m2 sr)", "[W m-2 sr-1]", "cd/m2"):
        au.write_text(f"theta_i,phi_i,theta_o,phi_o,r,g,b\n[deg],[deg],[deg],[deg],{unit},"
                      f"{unit},{unit}\n10,0,20,180,1,1,1\n")
        with pytest.raises(MeasurementsError, match=r"'b \[.*\]': a radiance, not a BRDF: "
                                                    r"brdffit reads a BRDF, in 1/sr"):
            read_measured(au)
    astm = tmp_path / "long.astm"
    astm.write_text("VARS theta_i,phi_i,theta_s,phi_s,wavelength,BRDF\n0.1,0,0.2,0,450,0.3\n")
    with pytest.raises(MeasurementsError, match="column 'wavelength' holds one wavelength "
                                                ".450 nm. alone: a spectrum needs several"):
        read_measured(astm)
    # HDF5: values in percent refused, CF packing applied
    for name, write, says in (
            ("percent.h5", lambda f: f["rgb"].attrs.__setitem__("units", "%"),
             "dataset rgb has units '%': a sample list's values are a BRDF, in 1/sr"),
            ("packed.h5", None, None)):
        path = tmp_path / name
        with h5py.File(path, "w") as f:
            for a, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), deg, strict=True):
                f.create_dataset(a, data=v).attrs["units"] = "degrees"
            if write is None:
                packed = f.create_dataset("rgb", data=np.round(s[4] / 1e-4).astype(np.uint16))
                packed.attrs["scale_factor"] = 1e-4
            else:
                f["rgb"] = s[4]
                write(f)
            f.attrs["units"] = "1/sr"  # the file's, meant for its values: not an angle unit
        if says is not None:
            with pytest.raises(MeasurementsError, match=re.escape(says)):
                read_measured(path)
        else:
            np.testing.assert_allclose(read_measured(path).rgb, plain.rgb, atol=6e-5)
    # German Excel with a date column, and pandas' index column
    lines = (tmp_path / "s.csv").read_text().splitlines()
    de = tmp_path / "de.csv"
    de.write_text("Datum;" + lines[0].replace(",", ";") + "\n" + "".join(
        "05.05.2024;" + line.replace(",", ";").replace(".", ",") + "\n" for line in lines[1:]))
    np.testing.assert_allclose(read_measured(de).rgb, plain.rgb, rtol=1e-15)
    indexed = tmp_path / "indexed.csv"
    indexed.write_text("," + lines[0] + "\n" + "".join(f"{k},{line}\n"
                                                        for k, line in enumerate(lines[1:])))
    np.testing.assert_allclose(read_measured(indexed).rgb, plain.rgb, rtol=1e-15)
    cornell = tmp_path / "cornell.astm"
    text = (tmp_path / "s.astm").read_text()
    cornell.write_text("COMMENT Measured with the gonioreflectometer\nCOMMENT RGB from 31 "
                       "spectral samples\n" + text)
    assert read_measured(cornell).provenance["header"]["COMMENT"].count("\n") == 1
    # an ASTM file in degrees is said to be so, in its own columns' names (it read "phi_o
    # is beyond +-720 degrees" of a phi_s of 295); a units row of "degree" is read
    deg_astm = tmp_path / "deg.astm"
    deg_astm.write_text(text.replace("\n".join(text.splitlines()[3:]), "\n".join(
        ",".join(repr(float(x)) for x in (*[d[k] for d in deg], *s[4][k])) for k in range(60))))
    with pytest.raises(MeasurementsError, match=r"an ASTM E1392 file's angles are radians, "
                                                r"and theta_i, phi_i, theta_s, phi_s hold "
                                                r"polar angles up to [\d.]+: degrees\?"):
        read_measured(deg_astm)
    singular = tmp_path / "singular.csv"
    singular.write_text("theta_i,phi_i,theta_o,phi_o,r,g,b\n"
                        "degree,degree,degree,degree,1/sr,1/sr,1/sr\n"
                        + "\n".join(lines[1:]) + "\n")
    np.testing.assert_allclose(read_measured(singular).rgb, plain.rgb, rtol=1e-15)
    # a thousands separator is said as one; an HDF5 unit stored as a one-element array
    grouped = tmp_path / "grouped.csv"
    grouped.write_text(lines[0] + "\n" + lines[1] + "\n" + '10,0,20,0,"1,069.5",0.5,0.5\n')
    with pytest.raises(MeasurementsError, match="'1,069.5' has a thousands separator"):
        read_measured(grouped)
    arrayed = tmp_path / "arrayed.h5"
    with h5py.File(arrayed, "w") as f:
        for a, v in zip(("theta_i", "phi_i", "theta_o", "phi_o"), deg, strict=True):
            f.create_dataset(a, data=v).attrs["units"] = np.array([b"degrees"])
        f["rgb"] = s[4]
    np.testing.assert_allclose(read_measured(arrayed).rgb, plain.rgb, rtol=1e-15)
