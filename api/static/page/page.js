// The brdffit service's page: every number and image comes from the /v1 routes
// (docs/service.md). No framework and no network beyond this server. Text from
// the server (table names, error details) is always set as textContent, never
// parsed as HTML.
"use strict";

const TOKEN_KEY = "brdffit-token";
const POLL_MS = 500;
const METRICS = ["log_rmse", "cube_root_rmse", "rmse_cos", "rel_peak_error", "psnr_db"];
const ACTIVE = new Set(["queued", "running"]);

const state = {
  table: null,   // {id, name, summary}
  job: null,     // the job shown in Results
  model: null,   // the model whose plots and exports are shown
  polling: null, // timer id
  blobs: [],     // object URLs of the images shown (revoked when replaced)
  tableNames: new Map(),  // table id -> name, for the jobs list
  choices: null, // /page/choices.json: the lists and the defaults the form starts with
};

const $ = (id) => document.getElementById(id);

// -- talking to the API ------------------------------------------------------------

class ApiError extends Error {
  constructor(status, detail) {
    super(status ? `${status}: ${detail}` : detail);
    this.status = status;
    this.detail = detail;
  }
}

function token() {
  return sessionStorage.getItem(TOKEN_KEY);
}

// One request; its error becomes an ApiError carrying the API's `detail`.
async function api(method, path, { json, body, contentType, as = "json" } = {}) {
  const headers = {};
  const sent = token();
  if (sent) headers.Authorization = `Bearer ${sent}`;
  if (json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(json);
  } else if (contentType) {
    headers["Content-Type"] = contentType;
  }
  let response;
  try {
    response = await fetch(path, { method, headers, body });
  } catch (e) {
    throw new ApiError(0, `the server did not answer (${e.message}); is it running?`);
  }
  if (!response.ok) {
    let detail = `${response.statusText || "error"} (no detail in the answer)`;
    try {
      const data = await response.json();
      if (data && typeof data.detail === "string") detail = data.detail;
    } catch (e) { /* not JSON: a proxy's page; keep the status text */ }
    // A refusal of a token already replaced is stale: requests sent together answer
    // one by one, and a late 401 for the wrong token reopened the form over the right one.
    if (response.status === 401 && sent === token()) askForToken(detail);
    throw new ApiError(response.status, detail);
  }
  if (response.status === 204) return null;
  if (as === "blob") return response.blob();
  return response.json();
}

function say(text, kind = "error") {
  const box = $("message");
  box.textContent = text;
  box.className = kind;
  box.hidden = false;
  // an error shows where the reader is: a failed export far down the page was said at
  // the top, thousands of pixels away, while its line went blank
  if (kind === "error") box.scrollIntoView({ block: "nearest" });
}

function clearMessage() {
  $("message").hidden = true;
}

// Run an action from a button: its error is shown, never thrown into the void.
function guarded(action) {
  return async (event) => {
    const button = event && event.currentTarget;
    if (button) button.disabled = true;
    try {
      await action(event);
    } catch (e) {
      say(e instanceof ApiError ? `Error ${e.message}` : `Error: ${e.message}`);
    } finally {
      if (button) button.disabled = false;
    }
  };
}

function askForToken(detail, refused = true) {
  // the button opens it too, where nothing was refused: it said "answered 401" all the same
  $("token-why").textContent = refused ? `The server answered 401: ${detail}` : detail;
  $("token-form").hidden = false;
  $("token-input").focus();
}

// -- small formatting helpers ------------------------------------------------------

function count(n) {  // a count of bins: 1,096,216, not 1.096216e+6
  return typeof n === "number" ? n.toLocaleString("en-US") : fmt(n);
}

function fmt(x, digits = 4) {
  if (x === null || x === undefined) return "–";
  if (typeof x !== "number") return String(x);
  if (x !== 0 && (Math.abs(x) < 1e-3 || Math.abs(x) >= 1e5)) return x.toExponential(digits - 1);
  return Number(x.toPrecision(digits)).toString();
}

function when(iso) {
  return iso ? new Date(iso).toLocaleString() : "";
}

function el(tag, text, attrs = {}) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = text;
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  return node;
}

function button(text, action, attrs = {}) {
  const b = el("button", text, { type: "button", ...attrs });
  b.addEventListener("click", guarded(action));
  return b;
}

function asList(v) {
  return Array.isArray(v) ? v : [v];
}

// "value ± error" for each parameter, flags as the CLI's report shows them.
function paramsCell(result) {
  const cell = el("td", null, { class: "params" });
  const u = result.uncertainty || {};
  const se = u.std_error || {}, flags = u.undetermined || {}, bounds = u.at_bound || {};
  const why = u.why || {};
  for (const [name, value] of Object.entries(result.params)) {
    const values = asList(value);
    const errors = se[name] === undefined ? values.map(() => null) : asList(se[name]);
    const undetermined = flags[name] === undefined ? values.map(() => false) : asList(flags[name]);
    const atBound = bounds[name] === undefined ? values.map(() => false) : asList(bounds[name]);
    const line = el("div", null, { class: "param" });
    line.append(el("span", name, { class: "pname" }), " = ");
    values.forEach((v, i) => {
      if (i) line.append(", ");
      const entry = values.length > 1 ? `${name}[${i}]` : name;
      const part = el("span", fmt(v));
      if (atBound[i]) {
        part.append(el("em", " at bound"));
      } else if (errors[i] !== null && errors[i] !== undefined) {
        part.append(` ± ${fmt(errors[i], 2)}`);
      }
      if (undetermined[i]) {
        part.append(el("span", "?", { class: "flag", title: why[entry] || "undetermined" }));
      }
      line.append(part);
    });
    cell.append(line);
  }
  // whether the data determine each layer (hover: why)
  for (const [layer, seen] of Object.entries(u.layers || {})) {
    cell.append(el("div", `layer ${layer}: ${seen.status}`,
      { class: `layer ${seen.status}`, title: seen.why }));
  }
  return cell;
}

// -- tables ------------------------------------------------------------------------

function chooseTable(table) {
  state.table = table;
  estimateSoon();
  const s = table.summary || {};
  const p = $("table-current");
  p.textContent = "";
  const what = s.input
    // a sample list (docs/measurements.md): fitted at its own directions, not binned
    ? ` (${count(s.input.samples)} samples, ${s.input.format}${s.input.sigma ? ", with sigma" : ""}`
      + `${s.input.spectral ? `, spectral under ${s.input.spectral.illuminant}` : ""}`
      // one row per (direction, channel), pivoted: said, as the CLI says it
      + `${s.input.long_layout ? `, pivoted from ${count(s.input.long_layout.rows)} rows, one `
        + `per sample and ${s.input.long_layout.column}` : ""}`
      + `${s.input.decimal_comma ? ", decimal commas" : ""}`
      // which sheet of a workbook, and the sheets passed over (they held no samples)
      + `${s.input.sheets > 1 ? `, sheet “${s.input.sheet}” of ${s.input.sheets}` : ""}`
      + `${(s.input.sheets_passed || []).map((x) => `; sheet “${x.sheet}” passed over: `
        + x.why).join("")}: `
      + `fitted at their own directions; ${count(s.measured_bins)} MERL bins hold one) `
    : ` (${count(s.measured_bins)} measured bins, ${count(s.unmeasured_bins)} unmeasured, `
      + `${count(s.nonfinite_bins)} non-finite) `;
  p.append("Table: ", el("strong", table.name), what,
    el("span", table.id.slice(0, 12), { class: "ids", title: table.id }));
}

async function uploadTable() {
  const file = $("upload-file").files[0];
  if (!file) throw new Error("choose a measured file first (MERL .binary, ASTM, CSV, HDF5, MATLAB .mat, NumPy .npz, Excel .xlsx)");
  clearMessage();
  say(`Uploading ${file.name} (${fmt(file.size / 1e6, 3)} MB)…`, "info");
  const sheet = $("sheet-input").value.trim();
  const named = sheet ? `&sheet=${encodeURIComponent(sheet)}` : "";
  const table = await api("POST", `/v1/tables?name=${encodeURIComponent(file.name)}${named}`,
    { body: file, contentType: "application/octet-stream" });
  chooseTable(table);
  say(`Uploaded ${table.name}.`, "info");
  await refreshLists();
}

async function useMaterial() {
  const name = $("material-select").value;
  if (!name) throw new Error("pick a material first");
  say(`Building the ${name} table (a second or two)…`, "info");
  const table = await api("POST", `/v1/materials/${encodeURIComponent(name)}`);
  chooseTable(table);
  say(`Using ${table.name}.`, "info");
  await refreshLists();
}

async function deleteTable(table, withFits) {
  if (withFits && !confirm(`Delete ${table.name} and every fit of it?`)) return;
  try {
    await api("DELETE", `/v1/tables/${table.id}${withFits ? "?with_fits=true" : ""}`);
  } catch (e) {
    // the API's way out is a query parameter; on the page it is the button beside
    if (e.status === 409 && e.detail.includes("?with_fits=true")) {
      throw new ApiError(409, e.detail.replace(/pass \?with_fits=true/,
        "use “Delete with its fits”"));
    }
    throw e;
  }
  // its fits went with it: the job shown, if one of them, is gone (its rows gave 404s)
  if (withFits && state.job && state.job.table_id === table.id) forgetJob();
  if (state.table && state.table.id === table.id) {
    state.table = null;
    estimateSoon();
    $("table-current").textContent = "No table chosen.";
  }
  say(`Deleted table ${table.name}.`, "info");
  await refreshLists();
}

// -- fitting -----------------------------------------------------------------------

// The body is the library's request (brdffit.request.FitRequest.to_dict()) and a table.
function fitRequest() {
  if (!state.table) throw new Error("choose a table first (upload, material, or Use in the list)");
  let models = "auto";
  if ($("mode-list").checked) {
    models = [...document.querySelectorAll("#model-boxes input:checked")].map((b) => b.value);
    if (!models.length) throw new Error("tick at least one model, or choose auto");
  }
  const options = { loss: $("loss-select").value };
  if ($("physical-input").checked) options.physical = true;
  for (const [key, input] of [["samples", $("samples-input")], ["starts", $("starts-input")],
                              ["max_steps", $("max-steps-input")]]) {
    if (input.value !== "") options[key] = Number(input.value);
  }
  const preset = $("scene-select").value;
  const scene = preset ? { preset } : null;
  // auto's rule: with a fixed model the service refuses it (422, shown), not ignores it
  const rule = {};
  if ($("tolerance-input").value !== "") rule.tolerance = Number($("tolerance-input").value);
  if ($("mono-input").checked) rule.mono_ks = true;
  const candidates = $("candidates-input").value.split(",").map((c) => c.trim()).filter(Boolean);
  if (candidates.length) rule.candidates = candidates;
  const body = { table_id: state.table.id, models, options, scene };
  if (models === "auto" || Object.keys(rule).length) body.rule = rule;
  return body;
}

// What the fit would cost, asked of the server as the form changes: a fit over its limits
// is said before it is sent, and a long one is known to be long.
let estimateAsked = 0;
let estimateTimer = null;

function estimateSoon() {
  if (estimateTimer !== null) clearTimeout(estimateTimer);
  estimateTimer = setTimeout(() => { estimateTimer = null; showEstimate(); }, 300);
}

async function showEstimate() {
  const line = $("fit-estimate");
  const asked = ++estimateAsked;
  let text = "", kind = "hint";
  if (state.table) {
    try {
      const cost = await api("POST", "/v1/fits/estimate", { json: fitRequest() });
      const memory = cost.memory_mib >= 1024 ? `${fmt(cost.memory_mib / 1024, 2)} GiB`
        : `${Math.round(cost.memory_mib)} MiB`;
      text = cost.accepted
        ? `estimated ~${fmt(cost.seconds, 2)} s of fitting once compiled, ${memory} at its peak`
        : cost.over_limits;  // "this fit is estimated over the server's limits: ..."
      if (!cost.accepted) kind = "hint over";
    } catch (e) {
      // a form not yet a request (no model ticked) or one the service refuses: the fit
      // button says why when pressed
      text = "";
    }
  }
  if (asked !== estimateAsked) return;  // a later change answered first
  line.textContent = text;
  line.className = kind;
}

async function startFit() {
  clearMessage();
  const request = fitRequest();
  // The previous job's results go away at once: nothing on screen may pass for the new fit's.
  $("results-panel").hidden = true;
  let job;
  try {
    job = await api("POST", "/v1/fits", { json: request });
  } catch (e) {
    if (state.job && state.job.status === "done") $("results-panel").hidden = false;
    throw e;
  }
  showJob(job);
  await refreshLists();
}

function stopPolling() {
  if (state.polling !== null) clearTimeout(state.polling);
  state.polling = null;
}

async function poll(jobId) {
  state.polling = null;
  let job;
  try {
    job = await api("GET", `/v1/fits/${jobId}`);
  } catch (e) {
    say(`Error ${e.message} (while following job ${jobId.slice(0, 8)})`);
    // The server gone for a moment, or its storage failing: keep following, slower.
    if (e.status === 0 || e.status === 503) state.polling = setTimeout(() => poll(jobId), 5000);
    return;
  }
  if (!state.job || state.job.id !== jobId) return; // another job was opened meanwhile
  showJob(job);
}

// Show a job: its progress while active, its results once done.
function showJob(job) {
  stopPolling();
  const changed = !state.job || state.job.id !== job.id || state.job.status !== job.status;
  state.job = job;
  // in the address: a reload opens it again (it lost the job, its table and its progress)
  if (location.hash !== `#job=${job.id}`) history.replaceState(null, "", `#job=${job.id}`);
  const box = $("job-state");
  box.hidden = false;
  const progress = $("job-progress");
  $("job-cancel").hidden = !ACTIVE.has(job.status);
  if (job.status === "running") {
    progress.value = job.progress ? job.progress.fraction : 0;
    // the time it has run: the bar moves between models only, and a one-model fit sat at
    // 0 for 85 s with no sign of life
    const ran = job.started_at ? Math.max(0, (Date.now() - Date.parse(job.started_at)) / 1000) : null;
    $("job-stage").textContent = `running: ${job.progress ? job.progress.stage : "starting"}`
      + ` (job ${job.id.slice(0, 8)}, ${job.models.join(", ")}`
      + `${ran === null ? "" : `, ${Math.round(ran)} s so far`})`;
  } else if (job.status === "queued") {
    progress.removeAttribute("value");
    $("job-stage").textContent = `queued (job ${job.id.slice(0, 8)})`
      + (job.note ? `: ${job.note}` : "");
  } else {
    progress.value = job.status === "done" ? 1 : 0;
    // its worker's time: null for a job that compiled its programs first
    const took = job.run_seconds == null ? "" : `, fitted in ${job.run_seconds.toFixed(1)} s`;
    $("job-stage").textContent = `${job.status} (job ${job.id.slice(0, 8)}${took})`
      + (job.reason ? `: ${job.reason}` : "") + (job.note ? ` (${job.note})` : "");
  }
  // its row in the jobs list says the same (it said "starting" through the whole fit);
  // the list itself is fetched again when the job ends
  const listed = $("jobs-table").querySelector(`tr[data-job="${CSS.escape(job.id)}"]`);
  if (listed) listed.replaceWith(jobRow(job));
  if (ACTIVE.has(job.status)) {
    state.polling = setTimeout(() => poll(job.id), POLL_MS);
    $("results-panel").hidden = true;
  } else {
    if (changed) refreshLists().catch((e) => say(`Error ${e.message}`));
    if (job.status === "done") {
      if (changed) showResults(job);
    } else {
      $("results-panel").hidden = true;
      if (job.status === "failed") say(`The fit failed: ${job.reason || "no reason given"}`);
    }
  }
}

async function cancelJob(job) {
  const after = await api("POST", `/v1/fits/${job.id}/cancel`);
  say(`Job ${job.id.slice(0, 8)} is ${after.status}.`, "info");
  if (state.job && state.job.id === job.id) showJob(after);
  await refreshLists();
}

// The shown job is gone from the server: nothing of it stays on screen or in the address.
function forgetJob() {
  stopPolling();
  state.job = null;
  state.model = null;
  history.replaceState(null, "", location.pathname + location.search);
  $("results-panel").hidden = true;
  $("job-state").hidden = true;
}

async function deleteJob(job) {
  if (!confirm(`Delete job ${job.id.slice(0, 8)} and its results?`)) return;
  await api("DELETE", `/v1/fits/${job.id}`);
  if (state.job && state.job.id === job.id) forgetJob();
  say(`Deleted job ${job.id.slice(0, 8)}.`, "info");
  await refreshLists();
}

async function openJob(job) {
  clearMessage();
  const fresh = await api("GET", `/v1/fits/${job.id}`);
  state.job = null; // shown anew, even when it is the job already on screen
  showJob(fresh);
  // its table becomes the chosen one: "Start the fit" refits it (it said "No table
  // chosen yet" above the job's results, and refused to start)
  const table = await api("GET", `/v1/tables/${fresh.table_id}`).catch(() => null);
  if (table) chooseTable(table);
}

// -- results -----------------------------------------------------------------------

function showResults(job) {
  $("results-panel").hidden = false;
  $("results-job").textContent = `job ${job.id.slice(0, 8)}`;
  const best = job.result;
  const selection = best && best.selection;
  $("selection-reason").textContent = selection
    ? `auto: ${selection.reason}`
    : `best log_rmse: ${best ? best.model : "none"}`;
  // the ranking is a plot of auto's choice: drawn from the chosen fit, whichever row is shown
  $("ranking-button").hidden = !selection;
  const body = $("results-table").querySelector("tbody");
  body.textContent = "";
  for (const r of job.results || []) {
    const row = el("tr", null, { "data-model": r.model });
    if (best && r.model === best.model) row.classList.add("best");
    row.append(el("td", r.model + (best && r.model === best.model ? " ★" : "")));
    for (const m of METRICS) row.append(el("td", fmt(r.error[m]), { class: "num" }));
    const q = r.quality || {};
    row.append(el("td", q.verdict || "—", { class: `verdict ${q.verdict || ""}`,
                                            title: q.reason || "not measured" }));
    row.append(paramsCell(r));
    const solve = el("td", (r.converged ? `${r.result}, ${r.steps} steps`
      : `NOT converged: ${r.result}, ${r.steps} steps`) + physicalNote(r.physical),
      { class: r.converged ? "" : "warn" });
    // where the fit did other than asked (more or fewer starts, a nested model's refits)
    for (const note of r.notes || []) solve.append(el("div", `note: ${note}`, { class: "note" }));
    row.append(solve);
    row.append(el("td", fmt(r.time_s, 3), { class: "num" }));
    row.addEventListener("click", () => showModel(r.model));
    body.append(row);
  }
  showNextSteps(best);
  showSamplesNote(best);
  $("export-report").textContent = "";
  $("extra-figure").hidden = true;
  showModel(best ? best.model : null);
}

// A sample list fitted at its own directions: where its samples are, and its held-out
// error (input.coverage; docs/measurements.md). Hidden for a MERL table.
function onSamples(r) {
  return Boolean(r && r.input && r.input.fitted_at === "samples");
}

function showSamplesNote(best) {
  const note = $("samples-note");
  note.hidden = !onSamples(best);
  if (note.hidden) return;
  const c = best.input.coverage;
  const peak = { true: "seen", false: "NOT seen: no sample within half its height" }[c.peak_seen]
    || "no lobe fitted";
  const held = best.error.held_out_log_rmse;
  note.textContent = `${best.input.samples} samples (${best.input.format}), fitted at their own `
    + `directions; held-out log_rmse ${fmt(held)} (${best.input.held_out ? best.input.held_out.folds : 0}-fold) `
    + `beside ${fmt(best.error.log_rmse)} in-sample. Coverage: ${c.regions.held} of `
    + `${c.regions.of} (theta_h, theta_d) regions; light ${c.theta_i_deg[0].toFixed(0)}-`
    + `${c.theta_i_deg[1].toFixed(0)} deg, view ${c.theta_o_deg[0].toFixed(0)}-`
    + `${c.theta_o_deg[1].toFixed(0)} deg${c.in_plane ? ", in-plane" : ""}; specular peak ${peak}. `
    + "The samples plot below shows each of them, fitted against measured.";
}

// What to try next where the chosen fit does not look good (quality.next), best first.
function showNextSteps(best) {
  const q = (best && best.quality) || {};
  const steps = q.next || [];
  const box = $("next-steps");
  box.hidden = steps.length === 0;
  const list = box.querySelector("ol");
  list.textContent = "";
  if (!steps.length) return;
  $("next-title").textContent = `${best.model} looks ${q.verdict}: ${q.reason}. What to try next:`;
  for (const s of steps) {
    const gain = s.gain_db == null ? "" : ` (${s.gain_db > 0 ? "+" : ""}${s.gain_db.toFixed(1)} dB)`;
    const item = el("li", null);
    item.append(el("code", s.try), document.createTextNode(`${gain}: ${s.why}`));
    const settings = stepSettings(s.try);
    if (settings) {
      const button = el("button", "Set up this fit", { type: "button", class: "set-up" });
      button.addEventListener("click", () => applySettings(settings, s.try));
      item.append(" ", button);
    }
    list.append(item);
  }
}

// A next step's `try` in the form's terms, or null where the form cannot make it (a step
// that is advice, "nothing here: ..."). Steps name brdffit fit's own flags: --model NAME
// (auto with --candidates LIST), --loss NAME, --starts N, --max-steps N, "without
// --physical"; a step with any other flag is left as text.
function stepSettings(text) {
  const settings = {};
  if (/^without --physical\b/.test(text)) return { physical: false };
  const flags = [...text.matchAll(/--([a-z-]+)(?:\s+([^\s()]+))?/g)];
  if (!flags.length) return null;
  for (const [, flag, value] of flags) {
    if (value === undefined) return null;
    if (flag === "model") settings.model = value;
    else if (flag === "candidates") settings.candidates = value;
    else if (flag === "loss") settings.loss = value;
    else if (flag === "starts") settings.starts = value;
    else if (flag === "max-steps") settings.max_steps = value;
    else return null;
  }
  if (settings.loss && ![...$("loss-select").options].some((o) => o.value === settings.loss)) {
    return null;
  }
  if (settings.model && settings.model !== "auto"
      && !document.querySelector(`#model-boxes input[value="${CSS.escape(settings.model)}"]`)) {
    return null;
  }
  return settings;
}

// The form's models, loss, starts, steps, bounds and auto's rule as a request had them:
// blank where it had the default, as the page starts (no request: the page's own start).
function setFormFrom(request) {
  const c = state.choices, d = c.defaults;
  const o = (request && request.options) || {};
  const models = request ? request.models : [c.auto];
  const auto = models.length === 1 && models[0] === c.auto;
  $(auto ? "mode-auto" : "mode-list").checked = true;
  for (const box of document.querySelectorAll("#model-boxes input")) {
    box.checked = !auto && models.includes(box.value);
  }
  const candidates = (request && request.rule && request.rule.candidates) || [];
  $("candidates-input").value = !auto || candidates.join() === d.candidates.join()
    ? "" : candidates.join(",");
  $("loss-select").value = o.loss || c.default_loss;
  $("starts-input").value = o.starts == null || o.starts === d.starts ? "" : String(o.starts);
  $("max-steps-input").value = o.max_steps == null || o.max_steps === d.max_steps
    ? "" : String(o.max_steps);
  $("physical-input").checked = Boolean(o.physical);
  const rule = (request && request.rule) || {};
  $("tolerance-input").value = rule.tolerance == null || rule.tolerance === d.tolerance
    ? "" : String(rule.tolerance);
  $("mono-input").checked = Boolean(rule.mono_ks);
}

// The form set as a step says. A step is a change to the fit it was given for (quality.py
// leaves "--loss render" out of a step for a fit under the render loss): what the step
// does not name is set back as the shown job had it, not left from an earlier step
// ("--model ggx3" after "... --loss render" kept the render loss). The table, the scene
// and the samples stay as they are; the user looks and starts the fit.
function applySettings(settings, text) {
  setFormFrom(state.job && state.job.request);
  if (settings.model === "auto") {
    $("mode-auto").checked = true;
    // auto fits its candidates, not the ticked models: ticks left from an earlier step
    // read as part of this fit (setting .checked fires no change: the mode stays auto)
    for (const box of document.querySelectorAll("#model-boxes input")) box.checked = false;
  } else if (settings.model) {
    $("mode-list").checked = true;
    // auto's rule with a fixed model is refused (422), not ignored: a step to one model
    // is not set up to be refused
    $("tolerance-input").value = "";
    $("mono-input").checked = false;
    for (const box of document.querySelectorAll("#model-boxes input")) {
      box.checked = box.value === settings.model;
    }
  }
  if (settings.model) $("candidates-input").value = settings.candidates || "";
  if (settings.loss) $("loss-select").value = settings.loss;
  if (settings.starts) $("starts-input").value = settings.starts;
  if (settings.max_steps) $("max-steps-input").value = settings.max_steps;
  if (settings.physical === false) $("physical-input").checked = false;
  estimateSoon();  // set in code: no input event says the form changed
  $("fit-panel").scrollIntoView({ block: "start" });
  const of = state.job ? ` (the rest as job ${state.job.id.slice(0, 8)} had it)` : "";
  say(`The form is set up for: ${text}${of}. Start the fit when it reads as you want.`, "info");
}

// A physically bounded fit: what the bounds cost against the unconstrained fit.
function physicalNote(p) {
  if (!p) return "";
  const c = p.relative_cost;
  const cost = c === null ? "n/a" : `${c < 0 ? "" : "+"}${(100 * c).toFixed(1)}%`;
  const active = p.active.length ? p.active.join("; ") : "no bound active";
  return `; physically bounded: log_rmse ${cost} against the unconstrained `
    + `${fmt(p.unconstrained_log_rmse)} (${active})`;
}

function showModel(model) {
  // another model's files are not this one's (a new job's results clear it too)
  if (model !== state.model) $("export-report").textContent = "";
  state.model = model;
  for (const row of $("results-table").querySelectorAll("tbody tr")) {
    row.classList.toggle("shown", row.dataset.model === model);
  }
  $("plots-model").textContent = model ? `(${model})` : "";
  for (const url of state.blobs) URL.revokeObjectURL(url);
  state.blobs = [];
  loadPlot("spheres", $("plot-spheres"));
  // a sample list's slices hold few samples: each sample, fitted against measured, says more
  const samples = onSamples((state.job.results || []).find((r) => r.model === model));
  $("slices-caption").textContent = samples
    ? "samples: each sample's fitted value against the measured one, and how far off it is "
      + "along theta_h (colour: theta_d)"
    : "slices: measured (dots) and fitted (lines) f_r against theta_h";
  loadPlot(samples ? "samples" : "slices", $("plot-slices"));
  $("extra-figure").hidden = true;
}

//: The plots with sphere renders: the exposure control re-renders them on the server
//: (before the tone curve, as a camera would), not brightens their pixels.
const EXPOSED = new Set(["spheres", "report"]);

function plotPath(kind) {
  const ev = Number($("exposure").value);
  const exposure = EXPOSED.has(kind) && ev ? `&exposure_ev=${ev}` : "";
  // auto's ranking is of its choice, not of the row shown
  const model = kind === "ranking" ? state.job.result.model : state.model;
  return `/v1/fits/${state.job.id}/plots/${kind}.png?model=${encodeURIComponent(model)}`
    + exposure;
}

// Images are fetched (not <img src>): a browser sends no token for an image.
async function loadPlot(kind, img) {
  const path = plotPath(kind);
  img.dataset.want = path;  // a slower, older request must not overwrite a newer one
  img.removeAttribute("src");
  img.alt = `${kind}: rendering…`;
  img.classList.add("loading");
  try {
    const blob = await api("GET", path, { as: "blob" });
    if (img.dataset.want !== path) return;
    const url = URL.createObjectURL(blob);
    state.blobs.push(url);
    img.src = url;
    img.alt = `${kind} plot of ${state.model}`;
    img.dataset.shown = path;
  } catch (e) {
    img.alt = `${kind}: ${e.message}`;
    say(`Error ${e.message} (the ${kind} plot)`);
  } finally {
    img.classList.remove("loading");
  }
}

async function showExtraPlot(event) {
  const kind = event.currentTarget.dataset.plot;
  $("extra-figure").hidden = false;
  $("extra-caption").textContent = kind === "ranking"
    ? `auto's ranking: every candidate it fitted, and why it chose ${state.job.result.model}`
    : `${kind} of ${state.model}`;
  await loadPlot(kind, $("plot-extra"));
}

function download(name, blob) {
  const url = URL.createObjectURL(blob);
  const a = el("a", null, { href: url, download: name });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

async function exportTo(event) {
  const target = event.currentTarget.dataset.export;
  const report = $("export-report");
  const jobId = state.job.id, model = state.model;
  // an export takes seconds to a minute: its answer is for the job and row it was asked
  // of; another shown by then does not get its report, nor its files downloaded
  const stillShown = () => state.job && state.job.id === jobId && state.model === model;
  report.textContent = `Exporting ${model} to ${target}…`;
  let out;
  try {
    out = await api("GET", `/v1/fits/${jobId}/exports/${target}`
      + `?model=${encodeURIComponent(model)}`);
  } catch (e) {
    if (!stillShown()) return;
    report.textContent = "";
    throw e;
  }
  if (!stillShown()) return;
  report.textContent = "";
  const f = out.fidelity || {};
  const head = el("p");
  head.append(el("strong", `${target}`), `: ${out.source_model} as ${f.target_model || "?"}`
    + (f.exact ? " (exact)" : `, log_rmse to the fit ${fmt(f.log_rmse_to_fit)}`)
    + (f.log_rmse_to_table != null
      ? `; as the renderer shades it, log_rmse to the table ${fmt(f.log_rmse_to_table)}`
        + ` (the fit's own: ${fmt(f.fit_log_rmse)})`
      : ` (the fit's own: ${fmt(f.fit_log_rmse)})`) + ". Files: ");
  for (const [name, text] of Object.entries(out.files)) {
    const blob = new Blob([text], { type: "application/octet-stream" });
    const link = el("a", name, { href: "#", class: "file" });
    link.addEventListener("click", (e) => { e.preventDefault(); download(name, blob); });
    head.append(link, " ");
    download(name, blob);
  }
  report.append(head);
  if (out.warnings.length) {
    const list = el("ul", null, { class: "warnings" });
    for (const w of out.warnings) list.append(el("li", w));
    report.append(el("p", "Warnings (every clamp and approximation):"), list);
  }
}

function downloadJson() {
  const job = state.job;
  download(`brdffit-fit-${job.id.slice(0, 8)}.json`,
    new Blob([JSON.stringify(job, null, 1)], { type: "application/json" }));
}

// -- the lists ---------------------------------------------------------------------

function emptyRow(columns, text) {
  const row = el("tr", null, { class: "empty" });
  row.append(el("td", text, { colspan: String(columns), class: "hint" }));
  return row;
}

//: Rows per page of each list (?page_size=N in the address changes it): a whole number in
//: 1 .. 500, as the lists' `limit` takes (1000 or 2.5 made both lists fail with a 422).
const PAGE = Math.min(500, Math.max(1, Math.round(
  Number(new URLSearchParams(location.search).get("page_size")) || 100)));

function tableRow(t) {
  const row = el("tr", null, { "data-table": t.id });
  row.append(el("td", t.name), el("td", t.id.slice(0, 12), { class: "ids", title: t.id }),
    el("td", count(t.summary.measured_bins), { class: "num" }), el("td", when(t.created_at)));
  const actions = el("td", null, { class: "actions" });
  actions.append(button("Use", async () => { chooseTable(t); clearMessage(); }),
    button("Delete", () => deleteTable(t, false)),
    button("Delete with its fits", () => deleteTable(t, true)));
  row.append(actions);
  return row;
}

function jobRow(j) {
  const row = el("tr", null, { class: `status-${j.status}`, "data-job": j.id });
  let outcome = j.reason || "";
  if (j.result) outcome = `${j.result.model}, log_rmse ${fmt(j.result.error.log_rmse)}`;
  if (j.progress) outcome = `${j.progress.stage}`;
  row.append(el("td", when(j.created_at)), el("td", j.status),
    el("td", j.models.join(", ")),
    el("td", state.tableNames.get(j.table_id) || j.table_id.slice(0, 12)),
    el("td", outcome));
  const actions = el("td", null, { class: "actions" });
  actions.append(button("Open", () => openJob(j)));
  if (ACTIVE.has(j.status)) actions.append(button("Cancel", () => cancelJob(j)));
  else actions.append(button("Delete", () => deleteJob(j)));
  row.append(actions);
  return row;
}

// One page of a list appended to its table, and a "Show older" row when the
// server has more (its next_cursor): nothing is silently left out.
function appendPage(tbody, page, { columns, rowOf, path, noun }) {
  const old = tbody.querySelector("tr.more");
  if (old) old.remove();
  for (const item of page.items) tbody.append(rowOf(item));
  if (!page.next_cursor) return;
  const shown = tbody.querySelectorAll("tr:not(.more):not(.empty)").length;
  const left = Math.max(page.total - shown, 0);
  const row = el("tr", null, { class: "more" });
  const cell = el("td", null, { colspan: String(columns) });
  const n = Math.min(PAGE, left);
  cell.append(button(`Show ${n} older ${n === 1 ? noun[0] : noun[1]} (${left} not shown)`, async () => {
    const next = await api("GET", `${path}?limit=${PAGE}&cursor=${page.next_cursor}`);
    appendPage(tbody, next, { columns, rowOf, path, noun });
  }));
  row.append(cell);
  tbody.append(row);
}

async function refreshLists() {
  const [tables, jobs] = await Promise.all([
    api("GET", `/v1/tables?limit=${PAGE}`), api("GET", `/v1/fits?limit=${PAGE}`),
  ]);
  state.tableNames = new Map(tables.items.map((t) => [t.id, t.name]));
  const tbody = $("tables-table").querySelector("tbody");
  tbody.textContent = "";
  if (!tables.items.length) tbody.append(emptyRow(5, "no tables yet"));
  appendPage(tbody, tables, { columns: 5, rowOf: tableRow, path: "/v1/tables", noun: ["table", "tables"] });
  const jbody = $("jobs-table").querySelector("tbody");
  jbody.textContent = "";
  if (!jobs.items.length) jbody.append(emptyRow(6, "no fit jobs yet"));
  appendPage(jbody, jobs, { columns: 6, rowOf: jobRow, path: "/v1/fits", noun: ["fit job", "fit jobs"] });
}

// -- start -------------------------------------------------------------------------

async function loadChoices() {
  const [choices, models, materials] = await Promise.all([
    api("GET", "/page/choices.json"), api("GET", "/v1/models"), api("GET", "/v1/materials"),
  ]);
  state.choices = choices;
  const loss = $("loss-select");
  loss.textContent = "";
  for (const name of choices.losses) loss.append(el("option", name, { value: name }));
  loss.value = choices.default_loss;
  const scene = $("scene-select");
  scene.querySelectorAll("option:not([value=''])").forEach((o) => o.remove());
  for (const name of choices.scene_presets) scene.append(el("option", name, { value: name }));
  $("samples-input").placeholder = String(choices.defaults.samples);
  $("starts-input").placeholder = String(choices.defaults.starts);
  $("max-steps-input").placeholder = String(choices.defaults.max_steps);
  $("candidates-input").placeholder = "default";
  $("candidates-label").title += ` (${choices.defaults.candidates.join(", ")}); sets: `
    + choices.candidate_sets.join(", ");
  $("tolerance-input").placeholder = String(choices.defaults.tolerance);
  const boxes = $("model-boxes");
  boxes.textContent = "";
  for (const m of models) {
    const label = el("label", null, { class: "choice", title: m.doc });
    const box = el("input", null, { type: "checkbox", value: m.name });
    box.addEventListener("change", () => { $("mode-list").checked = true; });
    label.append(box, ` ${m.name} (${m.n_params})`);
    boxes.append(label);
  }
  const select = $("material-select");
  select.textContent = "";
  select.append(el("option", materials.names.length ? "(choose)" : materials.note, { value: "" }));
  for (const name of materials.names) select.append(el("option", name, { value: name }));
}

async function start() {
  clearMessage();
  await loadChoices();
  await refreshLists();
  await openFromAddress();
}

// The job named in the address (#job=ID): at load (a reload, or a shared link) and when
// only the hash changes (a link pasted into the address bar reloads nothing).
async function openFromAddress() {
  const wanted = /^#job=([0-9a-f]+)$/.exec(location.hash);
  if (!wanted || (state.job && state.job.id === wanted[1])) return;
  await openJob({ id: wanted[1] }).catch(() => {
    // the address names the job shown again, if any: a reload opens what is on screen
    history.replaceState(null, "", location.pathname + location.search
      + (state.job ? `#job=${state.job.id}` : ""));
    say(`Job ${wanted[1].slice(0, 8)} of this address is no longer on the server.`, "info");
  });
}

let exposureTimer = null;

function setExposure() {
  const ev = Number($("exposure").value);
  $("exposure-value").textContent = `${ev >= 0 ? "+" : ""}${ev} EV`;
  // Re-rendered once the slider rests: one exposure for measurement and fit alike.
  clearTimeout(exposureTimer);
  exposureTimer = setTimeout(() => {
    if (!state.job || !state.model) return;
    loadPlot("spheres", $("plot-spheres"));
    const extra = $("extra-caption").textContent.split(" ")[0];
    if (!$("extra-figure").hidden && EXPOSED.has(extra)) loadPlot(extra, $("plot-extra"));
  }, 300);
}

document.addEventListener("DOMContentLoaded", () => {
  $("upload-button").addEventListener("click", guarded(uploadTable));
  $("material-button").addEventListener("click", guarded(useMaterial));
  $("fit-button").addEventListener("click", guarded(startFit));
  for (const kind of ["input", "change"]) $("fit-panel").addEventListener(kind, estimateSoon);
  $("job-cancel").addEventListener("click", guarded(() => cancelJob(state.job)));
  $("refresh-button").addEventListener("click", guarded(refreshLists));
  $("json-button").addEventListener("click", guarded(downloadJson));
  for (const b of document.querySelectorAll("[data-export]")) {
    b.addEventListener("click", guarded(exportTo));
  }
  for (const b of document.querySelectorAll("[data-plot]")) {
    b.addEventListener("click", guarded(showExtraPlot));
  }
  $("exposure").addEventListener("input", setExposure);
  window.addEventListener("hashchange", () => openFromAddress());
  $("token-open").addEventListener("click", () => askForToken(
    "Enter or change the token (kept for this browser tab).", false));
  $("token-form").addEventListener("submit", guarded(async (event) => {
    event.preventDefault();
    sessionStorage.setItem(TOKEN_KEY, $("token-input").value.trim());
    $("token-input").value = "";
    $("token-form").hidden = true;
    await start();
  }));
  $("token-clear").addEventListener("click", () => {
    sessionStorage.removeItem(TOKEN_KEY);
    $("token-form").hidden = true;
  });
  start().catch((e) => say(`Error ${e.message}`));
});
