/* fpscan web page: plan sensor masks, run scans, inspect results.
 *
 * Plain JavaScript, no build step, nothing fetched from elsewhere. Talks to the
 * service's HTTP API (docs/api.md; the full schema is /openapi.json):
 *   Plan view   GET /api/plans/kinds (the form's mask kinds and parameters),
 *               POST /api/plans/preview (debounced, as parameters change), POST /api/plans
 *   Scan view   GET /api/scanners, GET /api/plans, POST /api/scans, /pause /resume /abort,
 *               GET /api/jobs/{id}/events (Server-Sent Events, read with fetch so the
 *               bearer token can be sent and Last-Event-ID honoured on reconnect),
 *               GET /api/scans/{id}/preview (+ /preview/{plane}.png) for the live MIPs
 *   Jobs view   GET /api/jobs, GET /api/jobs/{id}, MIPs, depth slices, downloads,
 *               POST /api/reconstructions, POST /api/datasets (upload), POST .../cancel
 *               GET /api/reconstructions/methods (the method choices and their options),
 *               GET /api/formats (the upload's format choices, the export downloads)
 *               Disk use: GET /api/health (bytes by part), GET /api/datasets,
 *               DELETE /api/datasets/{id} (the storage section, its own functions below)
 * Units: every length, time, frequency and speed a form takes is a quantity field (text, its
 * unit shown after it): "60 µm", "0.06 mm", "60um" or a bare 60 in the shown unit. The server
 * reads the text with the one parser of every door (quantityText, below).
 * Sign-in: the page first asks GET /api/auth (no token needed) whether the server needs a
 * bearer token; if it does, a login view is shown before any other request, and the token
 * is kept in sessionStorage (this tab only) until "Sign out". A later 401 (the token was
 * changed on the server) shows the login view again and retries the request once. An address
 * ending in #token=TOKEN (the one `fpscan serve` prints with the token it made) signs in with
 * that token, and the fragment is taken out of the address bar and the history.
 */
"use strict";

const TOKEN_KEY = "fpscan.token";
const TERMINAL = new Set(["succeeded", "failed", "cancelled"]);
const $ = (id) => document.getElementById(id);

/* ------------------------------------------------------------------ API access */

class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
    this.detail = detail;
  }
}

function getToken() { return sessionStorage.getItem(TOKEN_KEY) || ""; }

/** The token of an address ending in #token=TOKEN (`fpscan serve` prints one with the token it
 *  made): kept for this tab, and the fragment replaced by the default view's, so that the token
 *  stays out of the history, bookmarks and screenshots. A fragment never reaches the server. */
function takeTokenFromAddress() {
  const m = /^#token=([^&]*)$/.exec(location.hash);
  if (!m) return;
  let token = "";
  try { token = decodeURIComponent(m[1]).trim(); } catch (_) { /* not percent-encoded UTF-8 */ }
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  history.replaceState(null, "", location.pathname + location.search + "#/plan");
}

/* The quantities the server's plausibility rules name, in the units the page's fields show them
 * (their data-unit / display_unit): a reason about one is worded in its field's unit. */
const FIELD_UNITS = {
  pitch: ["µm", 1e-6], dx: ["µm", 1e-6], dy: ["µm", 1e-6], depth: ["mm", 1e-3], dt: ["ns", 1e-9],
  prf: ["Hz", 1], "sound speed": ["m/s", 1],
};

/** A server reason worded for this page's fields. The server speaks to every client (the path
 *  "equisteradian.lattice.pitch:", "Numbers without a unit are SI", "--force"): here a value
 *  goes into a field that shows its unit and reads a bare number in it, so the reason names
 *  that field and its unit ("dt in ns: 8e+9 ns is implausible for a planar FP scanner
 *  (expected 100 ps to 1 µs) -- did you mean 8 ns (8ns)?", the suggestion as the command line
 *  gives it: the field takes "8ns" too), leaves out what bare numbers mean elsewhere and says to
 *  tick "another medium" where the command line says --force. Other reasons are returned as
 *  they are, but for that. */
function inFieldTerms(reason) {
  const text = String(reason);
  const forced = /force a value outside the range/.test(text);
  const bare = text.replace(/^(?:(?:[A-Za-z_][\w\-\[\]]*\.)*[A-Za-z_][\w\-\[\]]*: (?=[a-z]))+/, "");  // location paths
  const m = bare.match(/^(pitch|dx|dy|depth|dt|prf|sound speed) (-?[\d.]+(?:e[-+]?\d+)?) (m|s|Hz|m\/s) (.*)$/s);
  if (m && FIELD_UNITS[m[1]]) {
    const [unit, scale] = FIELD_UNITS[m[1]];
    const shownValue = Number((Number(m[2]) / scale).toPrecision(6));
    let rest = m[4].replace(/ ?Numbers without a unit.*$/s, "");
    if (forced) rest += "; tick “another medium” to accept it";
    return `${m[1]} in ${unit}: ${shownValue} ${unit} ${rest.trim()}`;
  }
  let out = text.replace(/; bare numbers are [^)]*\)/, ")");  // the parser's rule for the command line and JSON
  if (/ ?Numbers without a unit.*$/s.test(out)) {
    out = out.replace(/ ?Numbers without a unit.*$/s, "") + (forced ? "; tick “another medium” to accept it" : "");
  }
  return out.replace("force a value outside the range", "tick “another medium” for a value outside the range");
}

/* ------------------------------------------------------------------ quantity fields */

/* Every length, time, frequency and speed a form takes is a quantity field: text, its unit shown
 * after it, that reads "60 µm", "0.06 mm", "60um", "8ns", "1.5 km/s" or a bare number in the
 * shown unit. The page converts nothing: it sends the text (a bare number with the shown unit
 * written after it) and the server reads it with the parser of every door, the command line's
 * too (fpscan.driver.units.parse_quantity), refusing what it cannot read with the command
 * line's reason. One parser, so a value typed here gives the numbers (and the plan id) the same
 * text gives `fpscan plan`. */

/** A number without a unit, as the parser reads one (its own rule for what follows is the server's). */
const BARE_NUMBER = /^[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?$/i;
const QUANTITY_EXAMPLES = {
  m: "0.06 mm, 60um", mm: "60 µm, 0.06 mm", "µm": "0.06 mm, 60um", nm: "0.75 µm, 750nm",
  s: "10 min, 600s", ns: "0.02 µs, 20ns", Hz: "2 kHz, 50Hz", "m/s": "1.5 km/s, 1500m/s",
};

/** The text of a quantity typed in a field showing ``unit``: a bare number gets the unit
 *  written after it ("60" in a µm field: "60 µm"), anything else is sent as typed. */
function quantityText(text, unit) {
  const s = String(text).trim();
  return unit && BARE_NUMBER.test(s) ? `${s} ${unit}` : s;
}

/** Make ``input`` (in its label) a quantity field shown in ``unit``: text, the unit after it. */
function makeQuantityField(input, unit) {
  if (input.tagName === "INPUT") input.type = "text";
  input.removeAttribute("inputmode");  // letters too: the unit
  input.removeAttribute("pattern");
  input.spellcheck = false;
  input.autocomplete = "off";
  input.dataset.unit = unit;
  input.dataset.kind = "quantity";
  input.title = `in ${unit}, or with the unit written after the number (e.g. ${QUANTITY_EXAMPLES[unit] || "60um"})`;
  if (input.parentElement && input.parentElement.classList.contains("quantity")) return;
  const box = document.createElement("span");
  box.className = "quantity";
  input.replaceWith(box);
  const suffix = document.createElement("span");
  suffix.className = "unit";
  suffix.textContent = unit;
  box.append(input, suffix);
}

/** The value of quantity field ``id`` as text for the server (undefined when empty and ``optional``). */
function quantityValue(id, what, { optional = false } = {}) {
  const el = $(id);
  const raw = el.value.trim();
  if (raw === "") {
    if (optional) return undefined;
    throw new Error(`${what}: a value is needed`);
  }
  return quantityText(raw, el.dataset.unit);
}

/** A list typed in one field: comma- or semicolon-separated where the text has a comma or
 *  semicolon ("0.3 mm, -1 mm"), else space-separated where every part starts as a number does
 *  ("0.3 0", "0.3mm -1mm"); else one value ("0.75 µm"). */
function splitList(text) {
  const s = String(text).trim();
  if (/[,;]/.test(s)) return s.split(/[,;]/).map((p) => p.trim()).filter(Boolean);
  const parts = s.split(/\s+/).filter(Boolean);
  return parts.every((p) => /^[-+]?\.?\d/.test(p)) ? parts : (s ? [s] : []);
}

/** The server's reason from an error body: FastAPI's `detail` (a string, or a list of
 *  validation errors {loc, msg}), worded for this page's fields (:func:`inFieldTerms`). */
function detailText(body, status, statusText) {
  if (body && typeof body === "object" && "detail" in body) {
    const d = body.detail;
    if (typeof d === "string") return inFieldTerms(d);
    if (Array.isArray(d)) {
      return d.map((e) => {
        if (e && typeof e === "object") {
          const loc = Array.isArray(e.loc) ? e.loc.filter((p) => p !== "body").join(".") : "";
          return inFieldTerms((loc ? loc + ": " : "") + (e.msg || JSON.stringify(e)));
        }
        return String(e);
      }).join("; ");
    }
    return JSON.stringify(d);
  }
  if (typeof body === "string" && body.trim() && !/^\s*</.test(body)) return body.trim().slice(0, 300);
  return `HTTP ${status}${statusText ? " " + statusText : ""}`;
}

let loginWait = null; // resolves once the user has signed in (shared by concurrent requests)
let loginResolve = null;

/** The server's sign-in state: GET /api/auth (needs no token) -> {token_required,
 *  authenticated} for the token this tab holds. */
async function authState() {
  let resp;
  try {
    resp = await fetch("/api/auth", { headers: authHeaders() });
  } catch (err) {
    throw new ApiError(0, "cannot reach the server (" + err.message + ")");
  }
  let body = null;
  try { body = await resp.json(); } catch (_) { /* not JSON */ }
  if (!resp.ok) throw new ApiError(resp.status, detailText(body, resp.status, resp.statusText));
  return body;
}

/** Show the login view instead of the page's views, with `message` (the server's reason)
 *  when there is one. Resolves true once the user has signed in. */
function showLogin(message) {
  if (loginWait) return loginWait;  // already shown: requests refused meanwhile wait for the same sign-in
  document.body.dataset.tokenPrompts = String((Number(document.body.dataset.tokenPrompts) || 0) + 1);
  document.body.dataset.login = "1";
  for (const v of views) $("view-" + v).hidden = true;
  $("view-login").hidden = false;
  $("login-error").textContent = message || "";
  $("login-error").hidden = !message;
  $("login-token").value = "";
  $("login-token").focus();
  document.title = "fpscan — sign in";
  loginWait = new Promise((resolve) => { loginResolve = resolve; });
  return loginWait;
}

/** The login form: keep the token for this tab if the server takes it, else say why not. */
async function submitLogin(ev) {
  ev.preventDefault();
  const token = $("login-token").value.trim();
  if (!token) return;
  $("login-submit").disabled = true;
  sessionStorage.setItem(TOKEN_KEY, token);
  try {
    const state = await authState();
    if (state.token_required && !state.authenticated) {
      sessionStorage.removeItem(TOKEN_KEY);
      $("login-error").textContent = "The server refused this token (invalid bearer token). Check it and try again.";
      $("login-error").hidden = false;
      $("login-token").select();
      return;
    }
  } catch (err) {
    sessionStorage.removeItem(TOKEN_KEY);
    $("login-error").textContent = err instanceof ApiError ? err.detail : String(err);
    $("login-error").hidden = false;
    return;
  } finally {
    $("login-submit").disabled = false;
  }
  $("view-login").hidden = true;
  delete document.body.dataset.login;
  updateTokenButton();
  const resolve = loginResolve;
  loginWait = null;
  loginResolve = null;
  if (resolve) resolve(true);
}

function signOut() {
  sessionStorage.removeItem(TOKEN_KEY);
  updateTokenButton();
  showLogin("Signed out. Enter the token to sign in again.").then(() => route());
}

function authHeaders(extra) {
  const h = Object.assign({}, extra || {});
  const t = getToken();
  if (t) h["Authorization"] = "Bearer " + t;
  return h;
}

/** fetch with the token; on 401/403 ask for the token once and retry. Returns the
 *  Response (ok) or throws ApiError carrying the server's reason. */
async function apiFetch(path, options = {}, retried = false) {
  const opts = Object.assign({}, options);
  opts.headers = authHeaders(options.headers);
  if (options.json !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(options.json);
    delete opts.json;
  }
  let resp;
  try {
    resp = await fetch(path, opts);
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, "cannot reach the server (" + err.message + ")");
  }
  if (resp.ok) return resp;
  let body = null;
  const text = await resp.text();
  try { body = JSON.parse(text); } catch (_) { body = text; }
  const detail = detailText(body, resp.status, resp.statusText);
  if (resp.status === 401 && !retried) {  // the token was changed on the server: sign in again
    const msg = getToken()
      ? `The server refused the token this tab holds (${detail}). Sign in with the right token.`
      : `This server needs its access token (${detail}).`;
    if (await showLogin(msg)) {
      route();
      return apiFetch(path, options, true);
    }
  }
  throw new ApiError(resp.status, detail);
}

async function apiJson(path, options) {
  const resp = await apiFetch(path, options);
  if (resp.status === 204) return null;
  return resp.json();
}

/** A list from a response that is a list or {items|jobs|plans|scanners: [...]}. */
function asList(data, key) {
  if (Array.isArray(data)) return data;
  if (data && typeof data === "object") {
    for (const k of [key, "items", "results", "data"]) {
      if (k && Array.isArray(data[k])) return data[k];
    }
  }
  return [];
}

/** The job id from a 202 response: body `id`/`job_id`, else the Location header. */
async function jobIdFrom(resp) {
  let body = null;
  try { body = await resp.json(); } catch (_) { /* empty body */ }
  if (body && (body.id || body.job_id)) return String(body.id || body.job_id);
  const loc = resp.headers.get("Location") || "";
  const m = loc.match(/\/api\/jobs\/([^/?#]+)/);
  if (m) return decodeURIComponent(m[1]);
  throw new ApiError(resp.status, "the server did not say which job it started");
}

function newIdempotencyKey() {
  if (window.crypto && crypto.randomUUID) return crypto.randomUUID();
  return "k-" + Date.now().toString(36) + "-" + Math.random().toString(36).slice(2);
}

/* ------------------------------------------------------------------ errors */

function showError(err) {
  if (err && err.name === "AbortError") return;
  const msg = err instanceof ApiError ? err.detail : (err && err.message) || String(err);
  $("error-text").textContent = msg;
  $("error").hidden = false;
}
function clearError() { $("error").hidden = true; $("error-text").textContent = ""; }

/* ------------------------------------------------------------------ formatting */

function fmtDuration(s) {
  if (s === null || s === undefined || !isFinite(s)) return "–";
  s = Math.max(0, Number(s));
  if (s < 60) return s.toFixed(s < 10 ? 1 : 0) + " s";
  const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = Math.round(s % 60);
  return (h ? h + " h " : "") + m + " min " + (h ? "" : sec + " s");
}
function fmtNum(x, digits = 3) {
  if (x === null || x === undefined || x === "" || !isFinite(x)) return "–";
  const n = Number(x);
  return Math.abs(n) >= 1e4 || (Math.abs(n) < 1e-3 && n !== 0) ? n.toExponential(digits - 1) : String(+n.toPrecision(digits));
}
function shortId(id) { id = String(id); return id.length > 12 ? id.slice(0, 8) + "…" : id; }
function setState(el, state) {
  el.dataset.state = state || "";
  el.textContent = state || "–";
}

/** Show a PNG from the API in an <img> (fetched with the token; object URL). */
async function loadImage(img, path) {
  const resp = await apiFetch(path);
  setImageBlob(img, await resp.blob());
  img.dataset.src = path;
}

function setImageBlob(img, blob) {
  const old = img.dataset.objectUrl;
  const url = URL.createObjectURL(blob);
  img.src = url;
  img.dataset.objectUrl = url;
  if (old) URL.revokeObjectURL(old);
}

function clearImage(img) {
  if (img.dataset.objectUrl) URL.revokeObjectURL(img.dataset.objectUrl);
  delete img.dataset.objectUrl;
  delete img.dataset.src;
  img.removeAttribute("src");
}

/* ------------------------------------------------------------------ readable values */

/* The unit of each parameter the server's jobs, plans and results carry (SI on the wire:
 * docs/api.md), keyed by the parameter's own name (the last part of "params.dx",
 * "plan.acquisition.prf"): one map for every table of the page. "m→nm" are optical
 * wavelengths, shown in nm; "B" byte counts, shown with binary prefixes; names ending in
 * _s are durations, _m lengths, _nm nanometres, _hz frequencies, _bytes byte counts. */
const PARAM_UNITS = {
  dx: "m", dy: "m", dz: "m", pitch: "m", spacing: "m", depth: "m", poi_depth: "m", radius: "m",
  min_spacing: "m", aperture: "m", z_max: "m", z_min: "m",
  dt: "s", t0: "s",
  prf: "Hz", bandwidth: "Hz",
  c: "m/s", c_range: "m/s", sound_speed: "m/s", c_values: "m/s", sound_speed_range: "m/s",
  sound_speed_values: "m/s",
  wavelength_m: "m→nm", wavelengths: "m→nm", wavelengths_m: "m→nm", excitation_wavelengths: "m→nm",
  memory_estimate: "B", memory_bytes: "B", memory_limit: "B", size: "B",
};
const UNIT_SUFFIXES = [["_s", "duration"], ["_m", "m"], ["_nm", "nm"], ["_hz", "Hz"], ["_bytes", "B"]];
/* SI prefixes each unit is shown with (a sound speed stays in m/s, a length never in km) */
const UNIT_PREFIXES = {
  m: ["", "m", "µ", "n"], s: ["", "m", "µ", "n", "p"], Hz: ["G", "M", "k", ""], "m/s": [""], nm: [""],
};
const PREFIX_FACTOR = { G: 1e9, M: 1e6, k: 1e3, "": 1, m: 1e-3, "µ": 1e-6, n: 1e-9, p: 1e-12 };

/** The unit of parameter ``key`` ("params.dx" → "m"), or "" when it has none. */
function paramUnit(key) {
  const name = String(key).split(".").pop().toLowerCase();
  if (PARAM_UNITS[name]) return PARAM_UNITS[name];
  for (const [suffix, unit] of UNIT_SUFFIXES) if (name.endsWith(suffix)) return unit;
  return "";
}

/** A number to 4 significant digits without binary noise (0.30000000000000004 → "0.3"),
 *  a tiny or huge one in exponent form (1e-6, 1.235e+6). */
function fmtPlain(x) {
  const n = Number(x);
  if (Number.isInteger(n)) return String(n);
  const r = Number(n.toPrecision(4));
  return Math.abs(r) < 1e-3 || Math.abs(r) >= 1e6 ? r.toExponential() : String(r);
}

/** ``value`` in SI ``unit`` with the prefix that puts it in 1–1000 (100 µm, 12 ns, 1.5 kHz,
 *  1500 m/s); byte counts with binary prefixes (154 MiB); "m→nm" as nanometres. */
function fmtQuantity(value, unit) {
  const v = Number(value);
  if (!isFinite(v)) return String(value);
  if (unit === "duration") return fmtDuration(v);
  if (unit === "m→nm") return `${fmtPlain(v * 1e9)} nm`;
  if (unit === "B") {
    const names = ["B", "KiB", "MiB", "GiB", "TiB"];
    let k = 0, x = Math.abs(v);
    while (x >= 1024 && k < names.length - 1) { x /= 1024; k++; }
    return `${k ? String(Number((Math.sign(v) * x).toPrecision(3))) : String(v)} ${names[k]}`;
  }
  const prefixes = UNIT_PREFIXES[unit] || [""];
  if (v === 0) return `0 ${unit}`;
  let best = prefixes[prefixes.length - 1];
  for (const p of prefixes) { if (Math.abs(v) / PREFIX_FACTOR[p] >= 1 - 1e-9) { best = p; break; } }
  return `${fmtPlain(v / PREFIX_FACTOR[best])} ${best}${unit}`;
}

/** A parameter's value as shown: with its unit (:func:`paramUnit`), numbers without
 *  binary noise, lists item by item; null when there is nothing to show. */
function fmtParam(key, value) {
  if (value === null || value === undefined || value === "") return null;
  const unit = paramUnit(key);
  const one = (v) => (typeof v === "number" ? (unit ? fmtQuantity(v, unit) : fmtPlain(v)) : String(v));
  if (Array.isArray(value)) {
    if (value.every((v) => typeof v === "number" || typeof v === "string")) return value.map(one).join(", ");
    const s = JSON.stringify(value);
    return s.length > 200 ? s.slice(0, 200) + "…" : s;
  }
  const s = one(value);
  return s.length > 200 ? s.slice(0, 200) + "…" : s;
}

/** Table rows ``[name, shown value]`` of a nested object (names joined with "."), values
 *  formatted by :func:`fmtParam`; parameters without a value (null, unset) left out. */
function paramRows(obj, prefix = "", out = []) {
  if (obj && typeof obj === "object" && !Array.isArray(obj)) {
    for (const [k, v] of Object.entries(obj)) paramRows(v, prefix ? prefix + "." + k : k, out);
  } else {
    const shownValue = fmtParam(prefix, obj);
    if (shownValue !== null) out.push([prefix, shownValue]);
  }
  return out;
}

/** Fill a statistic's <dd> (and show it with its <dt>) or hide both when it does not
 *  apply to this job (``value`` null/undefined/""): no "–" placeholders. */
function setStat(id, value) {
  const dd = $(id);
  const none = value === null || value === undefined || value === "";
  dd.textContent = none ? "" : String(value);
  dd.hidden = none;
  const dt = dd.previousElementSibling;
  if (dt && dt.tagName === "DT") dt.hidden = none;
}

/** Clicking (or Enter/Space on) a picture in ``container`` shows it at full size in the
 *  picture dialog; Escape, the close button or a click outside closes it. */
function enlargeOnClick(container) {
  container.addEventListener("click", (ev) => {
    const img = ev.target.closest("img");
    if (img && img.getAttribute("src")) openPicture(img);
  });
  container.addEventListener("keydown", (ev) => {
    const img = ev.target.closest("img");
    if (img && img.getAttribute("src") && (ev.key === "Enter" || ev.key === " ")) { ev.preventDefault(); openPicture(img); }
  });
  for (const img of container.querySelectorAll("img")) {
    img.tabIndex = 0;
    img.classList.add("enlargeable");
    if (!img.title) img.title = "click to enlarge";
  }
}

function openPicture(img) {
  const dialog = $("picture-dialog");
  const big = $("picture-dialog-img");
  big.src = img.currentSrc || img.src;
  big.alt = img.alt;
  const cap = img.closest("figure") && img.closest("figure").querySelector("figcaption");
  $("picture-dialog-caption").textContent = cap ? cap.textContent : img.alt;
  if (!dialog.open) dialog.showModal();
}

function initPictureDialog() {
  const dialog = $("picture-dialog");
  $("picture-dialog-close").addEventListener("click", () => dialog.close());
  dialog.addEventListener("click", (ev) => { if (ev.target === dialog) dialog.close(); });
  dialog.addEventListener("close", () => $("picture-dialog-img").removeAttribute("src"));
  for (const box of document.querySelectorAll(".mips, #result-unmix figure, #result-slice-img")) {
    enlargeOnClick(box.tagName === "IMG" ? box.parentElement : box);
  }
}

/* ------------------------------------------------------------------ routing */

const views = ["plan", "scan", "jobs"];
let currentView = null;

function route() {
  if (document.body.dataset.login) return;  // signing in: the views wait
  const hash = location.hash.replace(/^#\/?/, "");
  const [view, arg] = hash.split("/");
  const name = views.includes(view) ? view : "plan";
  for (const v of views) {
    $("view-" + v).hidden = v !== name;
    const link = $("nav-" + v);
    if (v === name) link.setAttribute("aria-current", "page"); else link.removeAttribute("aria-current");
  }
  const changed = currentView !== name;
  const first = currentView === null;
  currentView = name;
  if (changed) clearError();
  document.title = "fpscan — " + $("nav-" + name).textContent;
  if (name === "plan" && changed && KINDS) schedulePreview(0);  // else buildMaskSelect previews once built
  if (name === "scan" && changed) refreshScanLists().catch(showError);
  if (name === "scan" && arg && decodeURIComponent(arg) !== scanJob) watchScan(decodeURIComponent(arg));
  if (name === "jobs") {
    refreshJobs().catch(showError);
    if (arg) openResult(decodeURIComponent(arg)).catch(showError); else closeResult();
  }
  // after a view change (not on first load), keyboard focus moves to the new view
  if (changed && !first) $("main").focus({ preventScroll: true });
}

/* ------------------------------------------------------------------ Plan view */

/* Mask kinds and their parameters come from the server (GET /api/plans/kinds, derived
 * from the parameter models in fpscan.service.plans.kinds): one entry per kind with a label, a
 * description and one descriptor per parameter {name, title, description, widget
 * (number | integer | numbers | pairs), integer, required, scalar, default, example, unit,
 * display_unit}. A parameter with a unit is a quantity field shown in its display unit
 * (makeQuantityField); its text goes to the server, which reads it (quantityText). */
let KINDS = null; // kind name -> {kind, label, description, aliases, fields}
const UNIT_SCALE = { m: 1, mm: 1e-3, "µm": 1e-6, nm: 1e-9, s: 1, ns: 1e-9, Hz: 1, "m/s": 1 };
const QUANTITY_UNITS = new Set(["m", "s", "Hz", "m/s"]);  // the SI units of the parser's kinds

function fieldId(name) { return "mask-" + name.replace(/_/g, "-"); }
function shownUnit(f) { return f.display_unit || f.unit || ""; }
function unitScale(f) { return UNIT_SCALE[shownUnit(f)] ?? 1; }
/** Whether parameter ``f`` is a quantity (a length, time, frequency or speed). */
function isQuantity(f) { return QUANTITY_UNITS.has(f.unit); }
/** A default or example (SI) shown in the field's display unit, without binary noise. */
function shown(v, f) { return typeof v === "number" ? Number((v / unitScale(f)).toPrecision(12)) : v; }

async function buildMaskSelect() {
  const list = await apiJson("/api/plans/kinds");
  KINDS = {};
  const sel = $("mask-kind");
  sel.textContent = "";
  for (const k of list) {
    KINDS[k.kind] = k;
    const o = document.createElement("option");
    o.value = k.kind;
    o.textContent = k.label;
    sel.appendChild(o);
  }
  sel.value = "equisteradian" in KINDS ? "equisteradian" : list[0].kind;
  renderMaskParams();
  // only the plan view previews (route() previews when it is opened later): a preview's
  // answer must not clear, nor show, an error in another view
  if (currentView === "plan") schedulePreview(0);
}

function renderMaskParams() {
  const k = KINDS && KINDS[$("mask-kind").value];
  const box = $("mask-params");
  box.textContent = "";
  if (!k) return;
  $("mask-help").textContent = k.description;
  for (const f of k.fields) {
    const label = document.createElement("label");
    const unit = shownUnit(f);
    const quantity = isQuantity(f);
    const hint = f.required ? "" : (f.default !== null && f.default !== undefined ? `, default ${shown(f.default, f)}${quantity ? " " + unit : ""}` : ", optional");
    label.textContent = `${f.title}${unit && !quantity ? " (" + unit + ")" : ""}${f.widget === "pairs" ? " — one pair per line" : ""}${hint} `;
    label.title = f.description;
    const input = document.createElement(f.widget === "pairs" ? "textarea" : "input");
    if (f.widget === "pairs") { input.rows = 6; input.cols = 24; }
    else if (f.widget === "numbers" || quantity) { input.type = "text"; }
    else { input.type = "number"; input.step = f.integer ? "1" : "any"; }
    input.id = fieldId(f.name);
    input.name = f.name;
    input.dataset.widget = f.widget;
    const initial = f.example ?? f.default;
    if (initial !== null && initial !== undefined) {
      if (f.widget === "pairs") input.value = initial.map((p) => p.map((v) => shown(v, f)).join(", ")).join("\n");
      else if (Array.isArray(initial)) input.value = initial.map((v) => shown(v, f)).join(", ");
      else input.value = shown(initial, f);
    }
    if (f.required) input.required = true;
    label.appendChild(input);
    if (quantity) makeQuantityField(input, unit);
    box.appendChild(label);
  }
}

/** One parameter's value from its input (undefined when empty): a quantity as text for the
 *  server (quantityText), any other number as a number. */
function maskValue(f) {
  const el = $(fieldId(f.name));
  const raw = el.value.trim();
  const what = f.title;
  if (raw === "") {
    if (f.required) throw new Error(`${what}: a value is needed`);
    return undefined;
  }
  const num = (s, where) => {
    if (isQuantity(f)) return quantityText(s, el.dataset.unit);
    const v = Number(s);
    if (s === "" || !isFinite(v)) throw new Error(`${what}${where}: "${s}" is not a number`);
    if (f.integer && !Number.isInteger(v)) throw new Error(`${what}${where}: must be a whole number`);
    return v;
  };
  if (f.widget === "pairs") {
    const pairs = [];
    raw.split(/\n/).forEach((line, i) => {
      line = line.trim();
      if (!line || line.startsWith("#")) return;
      const parts = splitList(line);
      if (parts.length !== 2) {
        throw new Error(`${what}, line ${i + 1}: "${line}" is not two values (x, y)${isQuantity(f) ? ": separate them with a comma" : ""}`);
      }
      pairs.push(parts.map((p) => num(p, `, line ${i + 1}`)));
    });
    if (!pairs.length) throw new Error(`${what}: give at least one pair`);
    return pairs;
  }
  if (f.widget === "numbers") {
    const vals = splitList(raw).map((p) => num(p, ""));
    return vals.length === 1 && f.scalar ? vals[0] : vals;
  }
  return num(raw, "");
}

/** A count typed in field ``id`` (a number; ``int``: a whole one). */
function numberField(id, what, { int = false, optional = false } = {}) {
  const el = $(id);
  const raw = el.value.trim();
  if (raw === "") {
    if (optional) return undefined;
    throw new Error(`${what}: a value is needed`);
  }
  const v = Number(raw);
  if (!isFinite(v)) throw new Error(`${what}: "${raw}" is not a number`);
  if (int && !Number.isInteger(v)) throw new Error(`${what}: must be a whole number`);
  return v;
}

/** The plan request body (PlanCreate in /openapi.json) from the form:
 *  {kind, lattice: {n_x, n_y, pitch}, params: {...}, acquisition: {...}}, counts as numbers,
 *  quantities as text the server reads ("60 µm"). Validation of values is the server's (its
 *  reason is shown); only counts that are not whole numbers are caught here. */
function planBody() {
  const kind = $("mask-kind").value;
  const k = KINDS && KINDS[kind];
  if (!k) throw new Error("the mask kinds are not loaded yet");
  const params = {};
  for (const f of k.fields) {
    const v = maskValue(f);
    if (v !== undefined) params[f.name] = v;
  }
  return Object.assign(planBodyCommon(), { kind, params });
}

function planBodyCommon() {
  const wl = splitList($("acq-wl").value).map((s) => quantityText(s, $("acq-wl").dataset.unit));
  return {
    lattice: {
      n_x: numberField("lat-nx", "n_x", { int: true }),
      n_y: numberField("lat-ny", "n_y", { int: true }),
      pitch: quantityValue("lat-pitch", "Pitch"),
    },
    acquisition: {
      n_t: numberField("acq-nt", "n_t", { int: true }),
      dt: quantityValue("acq-dt", "dt"),
      prf: quantityValue("acq-prf", "PRF"),
      averages: numberField("acq-avg", "Averages", { int: true }),
      wavelengths: wl,
      sound_speed: quantityValue("acq-c", "Sound speed"),
    },
    force: $("acq-force").checked, // a sound speed outside the plausible range (fpscan.driver.units' rule)
  };
}

let previewTimer = null;
let previewAbort = null;
let previewSeq = 0;
/** A preview refused with 429 is asked again after the server's Retry-After for busy
 *  slots (fpscan.service.api.context.Slots.retry_after_s, 5 s). */
const PREVIEW_RETRY_MS = 5000;

/** Preview the form after `delay` ms. The preview panel is aria-busy from now until the
 *  last scheduled preview has its answer (tests and screen readers wait on that). */
function schedulePreview(delay = 300) {
  clearTimeout(previewTimer);
  document.querySelector(".preview-panel").setAttribute("aria-busy", "true");
  previewTimer = setTimeout(() => {
    previewTimer = null;
    // left the plan view meanwhile (a retry after 429): route() previews when it is opened again
    if (currentView !== "plan") {
      if (!previewAbort) document.querySelector(".preview-panel").removeAttribute("aria-busy");
      return;
    }
    updatePreview().catch(showError);
  }, delay);
}

function countOf(points) {
  if (Array.isArray(points)) return points.length;
  if (points && typeof points === "object") return points.obtained ?? points.count ?? points.n;
  return points;
}

function showPlanStats(r) {
  const n = countOf(r.points ?? r.obtained_points ?? r.n_points ?? (r.mask && r.mask.obtained_points));
  const req = r.requested_points ?? (r.mask && r.mask.requested_points);
  $("plan-points").textContent = n === undefined ? "–" : (req && req !== n ? `${n} (asked ${req})` : String(n));
  $("plan-ratio").textContent = fmtNum(r.weight_ratio ?? (r.mask && r.mask.weight_ratio));
  $("plan-time").textContent = fmtDuration(r.expected_scan_time_s);
}

async function updatePreview() {
  if (previewAbort) previewAbort.abort();
  const panel = document.querySelector(".preview-panel");
  let body;
  try {
    body = planBody();
  } catch (err) {
    $("plan-preview-state").textContent = "Not previewed: " + err.message;
    panel.classList.add("stale");
    for (const k of ["plan-points", "plan-ratio", "plan-time"]) $(k).textContent = "–";
    if (!previewTimer && !previewAbort) panel.removeAttribute("aria-busy");
    return;
  }
  const ctl = new AbortController();
  previewAbort = ctl;
  panel.setAttribute("aria-busy", "true");
  $("plan-preview-state").textContent = "Updating preview…";
  try {
    const r = await apiJson("/api/plans/preview", { method: "POST", json: body, signal: ctl.signal });
    if (ctl.signal.aborted) return;
    const img = $("plan-preview");
    if (r.preview_png_base64) img.src = "data:image/png;base64," + r.preview_png_base64;
    img.alt = `Mask preview: ${KINDS[body.kind].label}, ${countOf(r.points)} points`;
    showPlanStats(r);
    previewSeq += 1;
    img.dataset.seq = String(previewSeq);
    $("plan-preview-state").textContent = `Preview up to date (${countOf(r.points)} points).`;
    panel.classList.remove("stale");
    if (currentView === "plan") clearError();  // not another view's error
  } catch (err) {
    if (err.name === "AbortError") return;
    $("plan-preview-state").textContent = "No preview: " + (err.detail || err.message);
    panel.classList.add("stale");
    for (const k of ["plan-points", "plan-ratio", "plan-time"]) $(k).textContent = "–";
    // the server is busy (429: its plan-request slots are full, e.g. with the previews of
    // earlier keystrokes): ask again for the form's latest parameters when it says to
    if (err instanceof ApiError && err.status === 429 && previewAbort === ctl) schedulePreview(PREVIEW_RETRY_MS);
    throw err;
  } finally {
    if (previewAbort === ctl) { previewAbort = null; if (!previewTimer) panel.removeAttribute("aria-busy"); }
  }
}

async function savePlan(ev) {
  ev.preventDefault();
  $("plan-saved").textContent = "";
  let body;
  try { body = planBody(); } catch (err) { showError(err); return; }
  const btn = $("plan-save");
  btn.disabled = true;
  try {
    const plan = await apiJson("/api/plans", { method: "POST", json: body });
    clearError();
    showPlanStats(plan);
    $("plan-saved").textContent = `Saved plan ${shortId(plan.id)} (${plan.n_points} points); pick it in the Scan view.`;
    $("plan-saved").dataset.planId = plan.id;
    lastSavedPlan = plan.id;
  } catch (err) {
    showError(err);
  } finally {
    btn.disabled = false;
  }
}

/* ------------------------------------------------------------------ Scan view */

let lastSavedPlan = null;
let scanJob = null;       // id of the job the scan view watches
let scanWatch = null;     // {stop()} of its watcher

function describePlan(p) {
  const kind = (p.mask && p.mask.kind) || p.kind || "";
  const n = countOf(p.obtained_points ?? p.n_points ?? p.points ?? (p.mask && p.mask.obtained_points));
  return `${shortId(p.id)} ${kind}${n !== undefined ? " · " + n + " points" : ""}`;
}

function placeholderOption(select, label) {
  const o = document.createElement("option");
  o.value = "";
  o.textContent = label;
  o.disabled = true;
  o.selected = true;
  select.appendChild(o);
}

let scanListsSeq = 0;
let scanPlans = new Map(); // id -> plan summary of the scan view's plan list

async function refreshScanLists() {
  const seq = ++scanListsSeq;
  const [scanners, plans] = await Promise.all([apiJson("/api/scanners"), apiJson("/api/plans")]);
  if (seq !== scanListsSeq) return; // a newer refresh is on its way
  const ssel = $("scan-scanner");
  const keepS = ssel.value;
  ssel.textContent = "";
  for (const s of asList(scanners, "scanners")) {
    const o = document.createElement("option");
    o.value = s.id ?? s.scanner_id ?? s.name;
    const status = s.status ?? s.state ?? "";
    o.textContent = `${o.value}${s.port || s.path ? " (" + (s.port || s.path) + ")" : ""}${status ? " — " + (typeof status === "string" ? status : JSON.stringify(status)) : ""}`;
    ssel.appendChild(o);
  }
  if (keepS) ssel.value = keepS;
  if (!ssel.value && ssel.options.length) ssel.selectedIndex = 0;
  if (!ssel.options.length) placeholderOption(ssel, "no scanner configured (fpscan serve --device ID=PATH)");
  const psel = $("scan-plan");
  const keepP = psel.value;
  psel.textContent = "";
  for (const p of asList(plans, "plans")) {
    const o = document.createElement("option");
    o.value = p.id;
    o.textContent = describePlan(p);
    psel.appendChild(o);
  }
  if (!psel.options.length) placeholderOption(psel, "no plan yet: save one in the Plan view");
  const want = lastSavedPlan || keepP; // a just-saved plan is preselected once
  if (want && [...psel.options].some((o) => o.value === want)) psel.value = want;
  if (lastSavedPlan && psel.value === lastSavedPlan) lastSavedPlan = null;
  scanPlans = new Map(asList(plans, "plans").map((p) => [p.id, p]));
  fillPreviewWavelengths();
}

/** The chosen plan's excitation wavelengths (m), [] when unknown. */
function planWavelengths(planId) {
  const p = scanPlans.get(planId);
  const w = p && p.acquisition && p.acquisition.wavelengths;
  return Array.isArray(w) ? w : [];
}

const nmText = (w) => `${fmtNum(w * 1e9)} nm`;

/** Replace a select's options by wavelengths ``ws`` (m; value = the index, text in nm)
 *  and ``extra`` [value, text] pairs after them. */
function setWavelengthOptions(sel, ws, extra = []) {
  sel.textContent = "";
  const pairs = ws.map((w, k) => [String(k), nmText(w)]).concat(extra);
  for (const [value, label] of pairs) {
    const o = document.createElement("option");
    o.value = value;
    o.textContent = label;
    sel.appendChild(o);
  }
}

/** Offer a multi-wavelength scan's wavelengths to the reconstruct form (the request's
 *  ``wavelength``: an index, or "all" for one volume per wavelength); one wavelength:
 *  the choice stays hidden. */
function fillReconWavelengths(ws) {
  setWavelengthOptions($("recon-wavelength"), ws, [["all", "all (one volume each)"]]);
  $("recon-wavelength-label").hidden = ws.length < 2;
}

/** Offer the chosen plan's wavelengths for the live preview (index = POST /api/scans
 *  preview_wavelength); one wavelength: nothing to choose. */
function fillPreviewWavelengths() {
  const sel = $("scan-preview-wavelength");
  const keep = sel.value;
  const ws = planWavelengths($("scan-plan").value);
  setWavelengthOptions(sel, ws);
  if (!ws.length) placeholderOption(sel, "the plan's wavelength");
  if (keep && Number(keep) < ws.length) sel.value = keep;
  sel.disabled = ws.length < 2;
}

function setScanButtons(state) {
  const active = state === "running" || state === "queued";
  $("scan-start").disabled = active || state === "paused";
  $("scan-pause").disabled = state !== "running";
  $("scan-resume").disabled = state !== "paused";
  $("scan-abort").disabled = !(active || state === "paused");
}

function showProgress(job) {
  const p = job.progress || {};
  if (job.state) { setState($("scan-state"), job.state); setScanButtons(job.state); }
  let frac = p.fraction;
  if ((frac === undefined || frac === null) && p.points_total) frac = p.points_done / p.points_total;
  if (frac !== undefined && frac !== null && isFinite(frac)) {
    $("scan-progress").value = frac;
    $("scan-progress-label").textContent = Math.round(frac * 100) + " %";
  }
  if (p.points_total !== undefined) $("scan-points").textContent = `${p.points_done ?? 0} / ${p.points_total}`;
  if (p.rate_per_s !== undefined) $("scan-rate").textContent = p.rate_per_s === null ? "–" : fmtNum(p.rate_per_s) + " A-lines/s";
  if (p.eta_s !== undefined) $("scan-eta").textContent = fmtDuration(p.eta_s);
  if (p.faults_recovered !== undefined) $("scan-faults").textContent = String(p.faults_recovered ?? 0);
}

/** Watch a job: Server-Sent Events read through fetch (so the token can be sent),
 *  reconnecting with Last-Event-ID; polls GET /api/jobs/{id} if the stream fails.
 *  Calls onJob(job-like object) with every update. Returns {stop()}. */
function watchJob(jobId, onJob) {
  let stopped = false;
  let lastId = null;
  let failures = 0;
  const ctl = new AbortController();
  const job = { id: jobId };
  const emit = (patch) => {
    if (patch.progress) job.progress = Object.assign({}, job.progress, patch.progress);
    for (const [k, v] of Object.entries(patch)) if (k !== "progress") job[k] = v;
    onJob(job);
    if (TERMINAL.has(job.state)) stop();
  };
  function stop() { stopped = true; ctl.abort(); }

  function handleEvent(ev) {
    document.body.dataset.sseEvents = String((Number(document.body.dataset.sseEvents) || 0) + 1);
    let data = ev.data;
    try { data = JSON.parse(ev.data); } catch (_) { /* plain text */ }
    if (ev.event === "state") {
      if (typeof data === "string") emit({ state: data });
      else emit(data.job ? data.job : data);
    } else if (ev.event === "progress" || ev.event === "message") {
      if (data && typeof data === "object") {
        if (data.progress || data.state) emit(data);
        else emit({ progress: data });
      }
    }
  }

  async function stream() {
    const headers = { Accept: "text/event-stream" };
    if (lastId !== null) headers["Last-Event-ID"] = lastId;
    const resp = await apiFetch(`/api/jobs/${encodeURIComponent(jobId)}/events`, { headers, signal: ctl.signal });
    const reader = resp.body.getReader();
    const decoder = new TextDecoder();
    let buf = "";
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      failures = 0;
      buf += decoder.decode(value, { stream: true }).replace(/\r\n?/g, "\n");
      let cut;
      while ((cut = buf.indexOf("\n\n")) >= 0) {
        const block = buf.slice(0, cut);
        buf = buf.slice(cut + 2);
        const ev = { event: "message", data: "", id: null };
        const data = [];
        for (const line of block.split("\n")) {
          if (!line || line.startsWith(":")) continue;
          const i = line.indexOf(":");
          const field = i < 0 ? line : line.slice(0, i);
          const val = i < 0 ? "" : line.slice(i + 1).replace(/^ /, "");
          if (field === "event") ev.event = val;
          else if (field === "data") data.push(val);
          else if (field === "id") ev.id = val;
        }
        if (ev.id !== null) lastId = ev.id;
        ev.data = data.join("\n");
        if (data.length) handleEvent(ev);
        if (stopped) return;
      }
    }
  }

  async function poll() {
    const j = await apiJson(`/api/jobs/${encodeURIComponent(jobId)}`);
    emit(j);
  }

  (async () => {
    try { await poll(); } catch (err) { showError(err); }
    while (!stopped) {
      try {
        if (failures < 3) await stream(); else await poll();
        if (!stopped) await poll(); // the stream ended: refresh the state
      } catch (err) {
        if (stopped || err.name === "AbortError") return;
        failures += 1;
        if (err instanceof ApiError && err.status >= 400 && err.status < 500 && err.status !== 408) {
          showError(err);
          if (err.status === 404) return;
        }
      }
      if (!stopped) await new Promise((r) => setTimeout(r, failures ? 1000 : 300));
    }
  })();
  return { stop };
}

let previewPoll = null;

function stopPreviewPoll() { clearInterval(previewPoll); previewPoll = null; }

async function refreshLivePreview(jobId) {
  let info;
  try {
    info = await apiJson(`/api/scans/${encodeURIComponent(jobId)}/preview`);
  } catch (err) {
    if (err instanceof ApiError && (err.status === 404 || err.status === 409)) return; // none yet
    throw err;
  }
  if (!info || !info.version || scanJob !== jobId) return; // version 0: no preview yet
  const version = String(info.version);
  const imgs = ["xy", "xz", "yz"].map((pl) => $("scan-mip-" + pl));
  if (imgs.every((img) => img.dataset.version === version)) return;
  await Promise.all(["xy", "xz", "yz"].map(async (pl, i) => {
    const resp = await apiFetch(`/api/scans/${encodeURIComponent(jobId)}/preview/${pl}.png?v=${encodeURIComponent(version)}`);
    const blob = await resp.blob();
    if (scanJob !== jobId) return; // another scan is watched now
    setImageBlob(imgs[i], blob);
    imgs[i].dataset.version = version;
    imgs[i].alt = `Live preview ${pl} MIP from ${info.points_used} points (version ${version})`;
  }));
  const shownAt = planWavelengths($("scan-plan").value)[info.wavelength_index ?? 0];
  $("scan-preview-info").textContent = `version ${version}, from ${info.points_used ?? "?"} points` +
    (shownAt !== undefined ? ` at ${nmText(shownAt)}` : "") +
    (info.updated ? `, updated ${new Date(typeof info.updated === "number" ? info.updated * 1000 : info.updated).toLocaleTimeString()}` : "");
}

function watchScan(jobId) {
  if (scanWatch) scanWatch.stop();
  stopPreviewPoll();
  scanJob = jobId;
  $("scan-job").textContent = shortId(jobId);
  $("scan-job").title = jobId;
  $("scan-open-job").href = "#/jobs/" + encodeURIComponent(jobId);
  $("scan-open-job").hidden = false;
  for (const pl of ["xy", "xz", "yz"]) {
    $("scan-mip-" + pl).dataset.version = "";
    clearImage($("scan-mip-" + pl));
  }
  $("scan-preview-info").textContent = "(none yet)";
  const tick = () => refreshLivePreview(jobId).catch(() => {});
  previewPoll = setInterval(tick, 1000);
  let planShown = false;
  scanWatch = watchJob(jobId, (job) => {
    if (scanJob !== jobId) return;
    showProgress(job);
    const p = job.params || {};
    if (!planShown && p.plan_id) { // show the job's own plan and scanner (after a reload too)
      for (const [id, v] of [["scan-plan", p.plan_id], ["scan-scanner", p.scanner_id]]) {
        if (v && [...$(id).options].some((o) => o.value === v)) {
          $(id).value = v;
          if (id === "scan-plan") planShown = true;
        }
      }
    }
    if (TERMINAL.has(job.state)) {
      // the last refresh may land shortly after the scan ends: keep looking a little while
      stopPreviewPoll();
      let left = 8;
      previewPoll = setInterval(() => { if (--left <= 0) stopPreviewPoll(); tick(); }, 1250);
      tick();
      if (job.state === "failed" && job.error) showError(new Error("Scan failed: " + (job.error.detail || job.error.message || job.error)));
    }
  });
}

async function startScan(ev) {
  ev.preventDefault();
  const plan_id = $("scan-plan").value, scanner_id = $("scan-scanner").value;
  if (!plan_id) { showError(new Error("Choose a plan (save one in the Plan view first).")); return; }
  if (!scanner_id) { showError(new Error("Choose a scanner.")); return; }
  const preview_wavelength = Number($("scan-preview-wavelength").value || 0);
  $("scan-start").disabled = true;
  try {
    const resp = await apiFetch("/api/scans", {
      method: "POST", json: { plan_id, scanner_id, ...(preview_wavelength ? { preview_wavelength } : {}) }, headers: { "Idempotency-Key": newIdempotencyKey() },
    });
    const id = await jobIdFrom(resp);
    clearError();
    for (const k of ["scan-points", "scan-rate", "scan-eta", "scan-faults"]) $(k).textContent = "–";
    $("scan-progress").value = 0;
    $("scan-progress-label").textContent = "0 %";
    setState($("scan-state"), "queued");
    setScanButtons("queued");
    watchScan(id);
    history.replaceState(null, "", "#/scan/" + encodeURIComponent(id)); // a reload re-attaches
  } catch (err) {
    showError(err);
    $("scan-start").disabled = false;
  }
}

async function scanControl(action) {
  if (!scanJob) return;
  try {
    const r = await apiFetch(`/api/scans/${encodeURIComponent(scanJob)}/${action}`, { method: "POST" });
    clearError();
    let body = null;
    try { body = await r.json(); } catch (_) { /* no body */ }
    if (body && body.state) showProgress(body);
  } catch (err) {
    showError(err);
  }
}

/* ------------------------------------------------------------------ Jobs view */

let jobsTimer = null;
const jobRows = new Map();

function jobProgressText(j) {
  const p = j.progress || {};
  let frac = p.fraction;
  if ((frac === undefined || frac === null) && p.points_total) frac = p.points_done / p.points_total;
  const pct = frac !== undefined && frac !== null && isFinite(frac) ? Math.round(frac * 100) + " %" : "–";
  const eta = !TERMINAL.has(j.state) && typeof p.eta_s === "number" ? `, ${fmtDuration(p.eta_s)} left` : "";
  return p.stage ? `${pct} (${p.stage}${eta})` : pct;
}

/* ------------------------------------------------------------------ iterative methods
 * The same words as the CLI (fpscan.service.progress: describe_iteration, outcome). */

/** "iteration 7/100, image change 0.021 (stops below 0.005)" from a job's progress fields
 *  (iteration, iterations_max, stop_rule, stop_value, stop_tol, stop_armed, stop_waits_for: what
 *  the method's rule waits for while not armed, in its own words, and stop_armed_at: the first
 *  iteration it can stop at); null without them. */
function iterationText(p) {
  if (p.iteration === undefined || p.iteration === null || !p.iterations_max) return null;
  let t = `iteration ${p.iteration}/${p.iterations_max}`;
  if (typeof p.stop_value === "number") {
    t += `, ${p.stop_rule || "stopping rule"} ${fmtNum(p.stop_value, 2)}`;
    let later = p.stop_armed === false ? ` once ${p.stop_waits_for || "armed"}` : "";
    if (p.stop_armed === false && typeof p.stop_armed_at === "number") later += `, from iteration ${p.stop_armed_at}`;
    if (typeof p.stop_tol === "number") t += p.stop_tol > 0 ? ` (stops below ${fmtNum(p.stop_tol, 2)}${later})` : " (tol 0: no early stop)";
  }
  return t;
}

/** What a running job is doing, for a person: its iteration and stopping rule, else its stage. */
function stageText(p) {
  const stage = String(p.stage || "");
  return (stage.startsWith("iteration") && iterationText(p)) || stage || "–";
}

function pctText(x) {
  const v = 100 * Number(x);
  return (Math.abs(v) >= 1 ? v.toFixed(1) : String(Number(v.toPrecision(2)))) + " %";
}

/** A field the method declares for its summary (GET /api/reconstructions/methods: summary;
 *  fpscan.service.progress.Shown) in words, from params_used: "0.0123 (automatic)",
 *  "3.1 % of the data, noise 3.0 %"; null without its value. */
function shownText(f, used) {
  const value = used[f.key];
  if (typeof value !== "number") return null;
  const fmt = (v) => (f.format === "percent" ? pctText(v) : fmtNum(v));
  let t = fmt(value);
  if (f.flag) {
    const on = !!used[f.flag];
    t += ` (${f.words[on ? 1 : 0]})`;
    if (on && value === 0 && f.note && used[f.note]) t += `: ${used[f.note]}`;
  }
  t += f.suffix || "";
  for (const [key, label] of f.also || []) {
    if (typeof used[key] === "number") t += `, ${label} ${fmt(used[key])}`;
  }
  return t;
}

/** How an iterative reconstruction ended, from its params_used (null for another method):
 *  {head: "converged after 37 iterations (image change 0.0041 < 0.005)", converged}; the
 *  fields its method declares follow it (shownText). */
function outcomeOf(used) {
  if (!used || used.iterations === undefined || used.iterations === null || used.converged === undefined) return null;
  const n = used.iterations;
  let rule = "";
  if (typeof used.iterate_change === "number" && typeof used.tol === "number") {
    rule = ` (image change ${fmtNum(used.iterate_change, 2)} ${used.iterate_change < used.tol ? "<" : "≥"} ${fmtNum(used.tol, 2)})`;
  }
  let head;
  // at the first iteration the rule could stop at (tv: after λ's continuation): as fpscan.service.progress.outcome
  const earliest = used.stop_armed_at === n ? ", the earliest the rule can stop" : "";
  if (used.converged) head = `converged after ${n} iterations${earliest}${rule}`;
  else if (used.stop_reason === "time limit") head = `not converged: stopped at the time limit after ${n} iterations${rule}`;
  else head = `not converged: stopped at the iteration limit, ${n}${used.max_iter ? " of " + used.max_iter : ""} iterations${rule}`;
  return { head, converged: !!used.converged };
}

/** The summary's rows of the fields the method declares (summary-<id>, before the grid's row),
 *  each filled with its value in words (shownText) once the method has an outcome. */
function renderDeclared(declared, used, o) {
  for (const old of document.querySelectorAll("#result-summary .summary-declared")) old.remove();
  const before = $("summary-grid").previousElementSibling;
  for (const f of declared) {
    const dt = document.createElement("dt");
    dt.textContent = f.title;
    dt.className = "summary-declared";
    const dd = document.createElement("dd");
    dd.id = "summary-" + f.id;
    dd.className = "summary-declared";
    before.before(dt, dd);
    setStat(dd.id, o ? shownText(f, used) : null);
  }
}

/** The running job's progress on its own page: bar, %, iteration (or stage), time left. */
function showResultProgress(job) {
  const active = !TERMINAL.has(job.state);
  $("result-progress").hidden = !active;
  if (!active) return;
  const p = job.progress || {};
  let frac = p.fraction;
  if ((frac === undefined || frac === null) && p.points_total) frac = p.points_done / p.points_total;
  if (frac !== undefined && frac !== null && isFinite(frac)) {
    $("result-progress-bar").value = frac;
    $("result-progress-pct").textContent = Math.round(frac * 100) + " %";
  }
  $("result-progress-stage").textContent = job.state === "queued" ? "queued" : stageText(p);
  $("result-progress-eta").textContent = typeof p.eta_s === "number" ? fmtDuration(p.eta_s)
    : (job.state === "running" ? "estimating…" : "–");
}

/** The result's summary, first on its page: method, outcome, the method's declared fields (tv: λ,
 *  residual), grid, time. */
function renderSummary(job) {
  const done = job.state === "succeeded" && job.kind !== "scan";
  $("result-summary").hidden = !done;
  if (!done) return;
  const r = resultOf(job);
  const used = r.params_used || {};
  const method = used.method || (job.params || {}).method;
  const title = METHODS && METHODS[method] ? `${method} (${METHODS[method].title})` : method;
  setStat("summary-method", title || null);
  const o = outcomeOf(used);
  setStat("summary-outcome", o ? o.head : null);
  $("summary-outcome").className = o ? (o.converged ? "outcome-converged" : "outcome-open") : "";
  renderDeclared((METHODS && METHODS[method] && METHODS[method].summary) || [], used, o);
  let grid = null;
  if (r.shape) {
    const axes = r.shape.length === 3 ? ["z", "y", "x"] : ["z", "x"];
    const steps = axes.map((a) => (typeof used["d" + a] === "number" ? `d${a} ${fmtQuantity(used["d" + a], "m")}` : null))
      .filter((v) => v);
    grid = `${r.shape.join(" × ")} (${axes.map((a) => "n_" + a).join(" × ")})` + (steps.length ? ", " + steps.join(", ") : "");
  }
  setStat("summary-grid", grid);
  const t = job.timings || {};
  const rt = r.timings || {};
  const parts = [];
  if (typeof rt.reconstruct_s === "number") parts.push(`reconstruct ${fmtDuration(rt.reconstruct_s)}`);
  if (typeof t.run_s === "number") parts.push(`job ${fmtDuration(t.run_s)}`);
  setStat("summary-time", parts.join(", ") || null);
}

function jobCreated(j) {
  const t = (j.timings && (j.timings.created ?? j.timings.created_at ?? j.timings.submitted)) ?? j.created_at ?? j.created;
  if (t === undefined || t === null) return "";
  const d = new Date(typeof t === "number" ? t * 1000 : t);
  return isNaN(d) ? String(t) : d.toLocaleString();
}

/** What a job works on: "plan 1a2b3c4d on fp1" (scan), "nedner of scan 5e6f7a8b" (recon). */
/** What a reconstruction's input samples (its record's params.mask): "full 96×96" or
 * "equisteradian, 400 of 9216 points"; "" for a record without it. The CLI's `fpscan jobs list`
 * says the same words (clients/cli/jobs.py: mask_words). */
function maskWords(m) {
  if (!m || !Array.isArray(m.lattice)) return "";
  const [nx, ny] = m.lattice;
  const all = nx * (ny || 1);
  const grid = ny > 1 ? `${nx}×${ny}` : `${nx}`;
  if (m.n_points === all) return `full ${grid}`;
  return `${m.kind ?? "points"}, ${m.n_points} of ${all} points`;
}

function jobWhat(j) {
  const p = j.params || {};
  const short = (s) => String(s ?? "?").slice(0, 8);
  if (j.kind === "scan") return `plan ${short(p.plan_id)} on ${p.scanner_id ?? "?"}`;
  let source = p.scan_job_id ? `scan ${short(p.scan_job_id)}` : `dataset ${short(p.dataset_id)}`;
  const m = p.mask;
  if (!p.scan_job_id && m && m.plan_id) source += ` sampled by plan ${short(m.plan_id)}`;
  const words = maskWords(m);
  return `${p.method ?? "?"} of ${source}` + (words ? ` (${words})` : "");
}

// the Jobs view shows a page of jobs (the table's data-page, 200): the newest, or those before jobsBefore (a job id)
function jobsPage() { return Number($("jobs-table").dataset.page) || 200; }
let jobsBefore = null;
async function refreshJobs() {
  const params = new URLSearchParams();
  if ($("jobs-state").value) params.set("state", $("jobs-state").value);
  if ($("jobs-kind").value) params.set("kind", $("jobs-kind").value);
  const pageSize = jobsPage();
  params.set("limit", String(pageSize + 1));  // one more than shown: whether an older page exists
  if (jobsBefore) params.set("before", jobsBefore);
  let jobs;
  try {
    jobs = asList(await apiJson("/api/jobs?" + params.toString()), "jobs");
  } catch (err) {
    if (!jobsBefore || err.status !== 404) throw err;
    jobsBefore = null;  // the page began at a job deleted since: back to the newest
    return refreshJobs();
  }
  const older = jobs.length > pageSize ? String(jobs[pageSize - 1].id) : null;
  jobs = jobs.slice(0, pageSize);
  $("jobs-older").hidden = !older;
  $("jobs-older").dataset.before = older || "";
  $("jobs-newest").hidden = !jobsBefore;
  $("jobs-paging").hidden = !older && !jobsBefore;
  const tbody = $("jobs-body");
  const seen = new Set();
  let prev = null;
  for (const j of jobs) {
    const id = String(j.id);
    seen.add(id);
    let tr = jobRows.get(id);
    if (!tr) {
      tr = document.createElement("tr");
      tr.dataset.jobId = id;
      tr.innerHTML = '<td class="c-id"></td><td class="c-kind"></td><td class="c-what"></td>' +
        '<td><span class="state c-state"></span></td>' +
        '<td class="c-progress"></td><td class="c-created"></td><td><a class="c-open"></a> ' +
        '<button type="button" class="c-delete danger">Delete</button></td>';
      const a = tr.querySelector(".c-open");
      a.href = "#/jobs/" + encodeURIComponent(id);
      a.textContent = "Open";
      a.setAttribute("aria-label", `Open job ${shortId(id)}`);
      const del = tr.querySelector(".c-delete");
      del.setAttribute("aria-label", `Delete job ${shortId(id)} and its files`);
      del.addEventListener("click", () => deleteJob(id).catch(showError));
      jobRows.set(id, tr);
    }
    tr.querySelector(".c-id").textContent = shortId(id);
    tr.querySelector(".c-id").title = id;
    tr.querySelector(".c-kind").textContent = j.kind ?? "";
    tr.querySelector(".c-what").textContent = jobWhat(j);
    setState(tr.querySelector(".c-state"), j.state);
    tr.querySelector(".c-progress").textContent = jobProgressText(j);
    tr.querySelector(".c-created").textContent = jobCreated(j);
    tr.querySelector(".c-delete").hidden = !TERMINAL.has(j.state);  // the server refuses active jobs
    tr.setAttribute("aria-selected", id === resultJob ? "true" : "false");
    // keep server order without re-creating rows (focus stays where it is)
    const want = prev ? prev.nextSibling : tbody.firstChild;
    if (want !== tr) tbody.insertBefore(tr, want);
    prev = tr;
  }
  for (const [id, tr] of jobRows) {
    if (!seen.has(id)) { tr.remove(); jobRows.delete(id); }
  }
  $("jobs-empty").hidden = jobs.length > 0;
  clearTimeout(jobsTimer);
  jobsTimer = setTimeout(() => { if (currentView === "jobs") refreshJobs().catch(() => {}); }, 3000);
}

let resultJob = null;
let resultWatch = null;

/** DELETE /api/jobs/{id}: the finished job and its files (after the user confirms). */
async function deleteJob(id) {
  if (!window.confirm(`Delete job ${shortId(id)} and its files (scan file or volume and pictures)?`)) return;
  clearError();
  await apiJson(`/api/jobs/${encodeURIComponent(id)}`, { method: "DELETE" });
  const tr = jobRows.get(id);
  if (tr) { tr.remove(); jobRows.delete(id); }
  if (resultJob === id) closeResult();
  $("jobs-empty").hidden = jobRows.size > 0;
}

function closeResult() {
  resultJob = null;
  $("recon-wavelength-label").hidden = true; // until the next scan's plan says it has several
  if (resultWatch) { resultWatch.stop(); resultWatch = null; }
  $("result").hidden = true;
}

/** A job's file in every export format of the server's registry (GET /api/formats): the
 *  job's export_<format> links, but the file itself (its own link), each titled by its format. */
function exportsOf(jobId, links, fileFormat) {
  const out = [];
  const id = encodeURIComponent(jobId);
  const names = links ? Object.keys(links).filter((k) => k.startsWith("export_")).map((k) => k.slice(7))
    : Object.values(FORMATS || {}).filter((f) => f.export_from === fileFormat).map((f) => f.name);
  for (const name of names) {
    const f = (FORMATS || {})[name] || { name, title: name, export_from: fileFormat, suffix: `-${name}`, folder: false };
    if (name === fileFormat) continue; // the file itself: its own link
    const path = links && links[`export_${name}`] ? links[`export_${name}`] : `/api/jobs/${id}/export/${encodeURIComponent(name)}`;
    out.push([f.folder ? `${f.title}, zipped` : f.title, path, `${jobId}${f.suffix}${f.folder ? ".zip" : ""}`]);
  }
  return out;
}

function downloadsFor(job) {
  const id = encodeURIComponent(job.id);
  const list = [];
  const params = job.params || {};
  const links = job.links || {};
  if (job.kind === "scan") {
    list.push(["Scan file (HDF5)", links.file || `/api/scans/${id}/file`, `scan-${job.id}.h5`]);
    list.push(...exportsOf(job.id, links, "fpscan"));
  } else {
    list.push(["Volume (HDF5)", links.volume || `/api/reconstructions/${id}/volume.h5`, `volume-${job.id}.h5`]);
    // the same volume for napari / ImageJ (row 0 at the top, as the pictures here), ...
    list.push(...exportsOf(job.id, links, "result"));
    // a job over every wavelength (wavelength "all" or unmix): one volume each
    for (const row of resultOf(job).wavelengths || []) {
      const nm = row.wavelength_nm !== null && row.wavelength_nm !== undefined ? ` at ${fmtNum(row.wavelength_nm)} nm` : "";
      list.push([`Volume${nm}, wavelength ${row.index} (HDF5)`,
        `/api/reconstructions/${id}/volume.h5?wavelength=${row.index}`, `volume-${job.id}-wavelength${row.index}.h5`]);
    }
    if (params.unmix) {
      list.push(["Unmixing: HbO2, Hb, THb, sO2, mask (HDF5)", `/api/reconstructions/${id}/unmix.h5`, `unmix-${job.id}.h5`]);
      list.push(["sO2 map (PNG)", `/api/reconstructions/${id}/so2.png`, `so2-${job.id}.png`]);
    }
    const scanId = params.scan_job_id;
    if (scanId) {
      const s = encodeURIComponent(scanId);
      list.push(["Scan file (HDF5)", `/api/scans/${s}/file`, `scan-${scanId}.h5`]);
      list.push(...exportsOf(scanId, null, "fpscan"));
    }
  }
  return list;
}

/** A download link: plain navigation when no token is set; with a token the file is
 *  fetched with the Authorization header and handed to the browser as a Blob. */
function downloadLink(label, path, filename) {
  const a = document.createElement("a");
  a.href = path;
  a.download = filename;
  a.textContent = label;
  a.addEventListener("click", async (ev) => {
    if (!getToken()) return;
    ev.preventDefault();
    try {
      const blob = await (await apiFetch(path)).blob();
      const url = URL.createObjectURL(blob);
      const tmp = document.createElement("a");
      tmp.href = url;
      tmp.download = filename;
      document.body.appendChild(tmp);
      tmp.click();
      tmp.remove();
      setTimeout(() => URL.revokeObjectURL(url), 60000);
    } catch (err) { showError(err); }
  });
  return a;
}

/** The job's result summary (``params.result``: {shape, max, points_used, timings}). */
function resultOf(job) {
  return (job.params && job.params.result) || job.result || {};
}

/** Depth spacing dz (m) of a result: the value the reconstruction used (depth row k lies
 *  at z = k·dz below the sensor plane, docs/architecture.md); null when the job does not say. */
function sliceSpacing(job) {
  const used = resultOf(job).params_used || {};
  return typeof used.dz === "number" && used.dz > 0 ? used.dz : null;
}

function sliceCount(job) {
  const r = resultOf(job);
  const cands = [r.shape && r.shape[0], r.n_z];
  for (const c of cands) if (Number.isInteger(c) && c > 0) return c;
  return null;
}

function renderResult(job) {
  $("result").hidden = false;
  $("result-id").textContent = shortId(job.id);
  $("result-id").title = job.id;
  $("result-kind").textContent = job.kind;
  setState($("result-state"), job.state);
  const err = job.error;
  $("result-error").textContent = err ? "— " + (typeof err === "string" ? err : err.detail || err.message || JSON.stringify(err)) : "";
  const active = !TERMINAL.has(job.state);
  $("result-cancel").hidden = !active;
  $("result-watch").hidden = !(active && job.kind === "scan");
  $("result-watch").href = "#/scan/" + encodeURIComponent(job.id);

  showResultProgress(job);
  renderSummary(job);
  const tbody = $("result-params").tBodies[0];
  tbody.textContent = "";
  const addRows = (rows) => {
    for (const [k, v] of rows) {
      const tr = document.createElement("tr");
      const a = document.createElement("td"); a.textContent = k;
      const b = document.createElement("td"); b.textContent = v;
      tr.append(a, b);
      tbody.appendChild(tr);
    }
    $("result-params-count").textContent = String(tbody.rows.length);
  };
  // what was asked (unset options left out) and, once done, the values the reconstruction used
  addRows(paramRows(job.params || {}).filter(([k]) => !k.startsWith("result.")));
  const used = resultOf(job).params_used;
  if (used) addRows(paramRows(used, "used"));
  const t = job.timings || {};
  addRows([["time queued", t.queued_s], ["time running", t.run_s]]
    .filter(([, v]) => v !== null && v !== undefined).map(([k, v]) => [k, fmtDuration(v)]));
  const rt = resultOf(job).timings;
  if (rt) addRows(paramRows(rt, "result timings"));
  const planId = job.params && job.params.plan_id;
  const planImg = $("result-plan-preview");
  planImg.closest("figure").hidden = !(job.kind === "scan" && planId);
  if (job.kind === "scan" && planId) {
    const pid = encodeURIComponent(planId);
    loadImage(planImg, `/api/plans/${pid}/preview.png`).catch(() => {});
    apiJson(`/api/plans/${pid}`).then((plan) => {
      if (resultJob !== job.id) return;
      fillReconWavelengths((plan.acquisition && plan.acquisition.wavelengths) || []);
      addRows(paramRows({ kind: plan.kind, n_points: plan.n_points, requested_points: plan.requested_points,
        weight_ratio: plan.weight_ratio, expected_scan_time_s: plan.expected_scan_time_s,
        lattice: plan.lattice, acquisition: plan.acquisition }, "plan"));
    }).catch(() => {});
  }
  const ul = $("result-downloads");
  ul.textContent = "";
  const done = job.state === "succeeded";
  for (const [label, path, fn] of downloadsFor(job)) {
    const li = document.createElement("li");
    if (done || (job.kind === "scan" && label.startsWith("Scan file"))) li.appendChild(downloadLink(label, path, fn));
    else li.textContent = label + " (when the job has succeeded)";
    ul.appendChild(li);
  }

  $("result-scan").hidden = !(job.kind === "scan" && done);
  if (job.kind === "scan" && done) listScanRecons(job.id).catch(showError);
  const isRecon = job.kind !== "scan";
  $("result-recon").hidden = !(isRecon && done);
  if (isRecon && done) {
    const id = encodeURIComponent(job.id);
    const links = job.links || {};
    const hasLinks = Object.keys(links).some((k) => k.startsWith("mip_"));
    for (const pl of ["xy", "xz", "yz"]) {
      const img = $("result-mip-" + pl);
      const fig = img.closest("figure");
      const path = hasLinks ? links["mip_" + pl] : `/api/reconstructions/${id}/mip/${pl}.png`;
      fig.hidden = !path; // a 2-D image has only the xz plane
      if (path) loadImage(img, path).catch(showError);
    }
    const n = sliceCount(job);
    // a 2-D image is its own xz picture: a depth "slice" of it would be one row
    $("result-slice-box").hidden = Array.isArray(resultOf(job).shape) && resultOf(job).shape.length === 2;
    const slider = $("result-slice");
    const dz = sliceSpacing(job);
    slider.dataset.dz = dz === null ? "" : String(dz);
    slider.max = String(n ? n - 1 : 0);
    slider.disabled = !n;
    // the slice opens at the depth of the volume's maximum (the middle depth may be pure noise)
    const peak = resultOf(job).max_index;
    const start = Array.isArray(peak) && Number.isInteger(peak[0]) ? peak[0] : (n ? Math.floor((n - 1) / 2) : 0);
    if (slider.dataset.job !== String(job.id)) { slider.value = String(start); slider.dataset.job = String(job.id); }
    if (Number(slider.value) > Number(slider.max)) slider.value = slider.max;
    const r = resultOf(job);
    $("scale-max").textContent = r.max !== undefined ? `slice maximum (volume maximum ${fmtNum(r.max)})` : "slice maximum";
    setStat("result-shape", r.shape ? r.shape.join(" × ") + (r.shape.length === 3 ? " (n_z × n_y × n_x)" : " (n_z × n_x)") : null);
    setStat("result-points", r.points_used ?? (r.params_used || {}).n_points);
    renderAutofocus(r.autofocus);
    renderUnmix(job, r.unmix);
    showSlice();
  }
}

/** The autofocus summary (``result.autofocus``: sound_speed, sound_speed_range,
 *  sound_speed_values, sharpness, time_s, evaluations, decimation; an older server named
 *  the speeds c, c_range, c_values) as text and an SVG curve with the chosen c marked. */
function renderAutofocus(found) {
  const box = $("result-autofocus");
  box.hidden = !found;
  if (!found) return;
  const af = { ...found, c: found.sound_speed ?? found.c, c_range: found.sound_speed_range ?? found.c_range,
    c_values: found.sound_speed_values ?? found.c_values };
  $("result-af-c").textContent = fmtNum(af.c, 5);
  $("result-af-range").textContent = (af.c_range || []).map((v) => fmtNum(v, 5)).join("–");
  $("result-af-time").textContent = fmtDuration(af.time_s);
  $("result-af-evals").textContent = String(af.evaluations ?? "–");
  $("result-af-q").textContent = String(af.decimation ?? "–");
  const svg = $("result-af-curve");
  svg.textContent = "";
  const cs = af.c_values || [], ss = af.sharpness || [];
  if (cs.length < 2) return;
  const W = 420, H = 180, L = 48, R = 10, T = 10, B = 30;
  const [c0, c1] = af.c_range && af.c_range.length === 2 ? af.c_range : [Math.min(...cs), Math.max(...cs)];
  const s1 = Math.max(...ss), s0 = Math.min(0, Math.min(...ss));
  const X = (c) => L + (W - L - R) * (c - c0) / ((c1 - c0) || 1);
  const Y = (v) => H - B - (H - T - B) * (v - s0) / ((s1 - s0) || 1);
  const NS = "http://www.w3.org/2000/svg";
  const el = (name, attrs, text) => {
    const e = document.createElementNS(NS, name);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
    if (text !== undefined) e.textContent = text;
    svg.appendChild(e);
    return e;
  };
  el("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "currentColor" });
  el("line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "currentColor" });
  el("text", { x: L, y: H - 8, "font-size": 11 }, `${fmtNum(c0, 5)} m/s`);
  el("text", { x: W - R - 70, y: H - 8, "font-size": 11 }, `${fmtNum(c1, 5)} m/s`);
  el("text", { x: 2, y: T + 10, "font-size": 11 }, "sharp.");
  el("polyline", { fill: "none", stroke: "#1f77b4", "stroke-width": 2,
    points: cs.map((c, i) => `${X(c).toFixed(1)},${Y(ss[i]).toFixed(1)}`).join(" ") });
  for (let i = 0; i < cs.length; i++) el("circle", { cx: X(cs[i]).toFixed(1), cy: Y(ss[i]).toFixed(1), r: 2.5, fill: "#1f77b4" });
  el("line", { x1: X(af.c), y1: T, x2: X(af.c), y2: H - B, stroke: "#d62728", "stroke-dasharray": "4 3" });
  el("text", { x: Math.min(X(af.c) + 4, W - 90), y: T + 12, "font-size": 11, fill: "#d62728" }, `c = ${fmtNum(af.c, 5)}`);
}

/** The unmixing summary (``result.unmix``) and the masked sO2 picture. */
function renderUnmix(job, u) {
  $("result-unmix").hidden = !u;
  if (!u) return;
  const id = encodeURIComponent(job.id);
  loadImage($("result-so2"), `/api/reconstructions/${id}/so2.png`).catch(showError);
  setStat("result-unmix-wavelengths", fmtParam("wavelengths_m", u.wavelengths_m || []));
  $("result-unmix-median").textContent = u.so2_median === null || u.so2_median === undefined ? "none (all masked)" : fmtNum(u.so2_median);
  setStat("result-unmix-masked", u.masked_fraction !== undefined && u.masked_fraction !== null ? `${(100 * u.masked_fraction).toFixed(1)} %` : null);
  $("result-unmix-threshold").textContent = u.threshold !== undefined ? `${(100 * u.threshold).toFixed(0)} %` : "the threshold";
}

/** The reconstruction jobs made from scan ``scanId`` (from the job list). */
async function listScanRecons(scanId) {
  // filtered by the server: every reconstruction of the scan, not those among the newest jobs only
  const q = new URLSearchParams({kind: "recon", scan_job_id: scanId, limit: "1000"});
  const jobs = asList(await apiJson("/api/jobs?" + q.toString()), "jobs");
  const ul = $("scan-recons");
  ul.textContent = "";
  if (!jobs.length) { const li = document.createElement("li"); li.textContent = "none yet"; ul.appendChild(li); }
  for (const j of jobs) {
    const li = document.createElement("li");
    const a = document.createElement("a");
    a.href = "#/jobs/" + encodeURIComponent(j.id);
    a.textContent = `${shortId(j.id)} · ${j.params.method}`;
    const st = document.createElement("span");
    st.className = "state";
    setState(st, j.state);
    li.append(a, " ", st);
    ul.appendChild(li);
  }
}

let sliceTimer = null;
function showSlice() {
  if (!resultJob) return;
  const k = Number($("result-slice").value);
  const dz = Number($("result-slice").dataset.dz);
  const depth = dz > 0 ? `z = ${(k * dz * 1e3).toFixed(3)} mm` : "";
  $("result-slice-value").textContent = `${k} of 0–${$("result-slice").max}`;
  $("result-slice-depth").textContent = depth ? `(${depth})` : "";
  clearTimeout(sliceTimer);
  const id = resultJob;
  sliceTimer = setTimeout(() => {
    const img = $("result-slice-img");
    loadImage(img, `/api/reconstructions/${encodeURIComponent(id)}/slice.png?index=${k}`)
      .then(() => {
        img.alt = `Reconstruction, depth slice ${k}` + (depth ? ` at ${depth}` : "");
        $("result-slice-caption").textContent = `depth slice ${k}` + (depth ? ` (${depth})` : "");
      })
      .catch(showError);
  }, 120);
}

async function openResult(jobId) {
  if (resultJob === jobId && !$("result").hidden) return;
  closeResult();
  resultJob = jobId;
  const job = await apiJson(`/api/jobs/${encodeURIComponent(jobId)}`);
  if (resultJob !== jobId) return;
  renderResult(job);
  $("result-heading").focus({ preventScroll: false });
  for (const tr of jobRows.values()) tr.setAttribute("aria-selected", tr.dataset.jobId === jobId ? "true" : "false");
  if (!TERMINAL.has(job.state)) {
    let lastState = job.state;
    resultWatch = watchJob(jobId, async (j) => {
      if (resultJob !== jobId) return;
      setState($("result-state"), j.state);
      showResultProgress(j);
      if (j.state !== lastState && TERMINAL.has(j.state)) {
        lastState = j.state;
        if (currentView === "jobs") refreshJobs().catch(() => {});
        try { renderResult(await apiJson(`/api/jobs/${encodeURIComponent(jobId)}`)); } catch (err) { showError(err); }
      }
      lastState = j.state;
    });
  }
}

/** A sound-speed field (a quantity field in m/s that also takes "auto"): empty → undefined,
 *  "auto" → "auto", else its text for the server ("1500 m/s", "1.5 km/s"; quantityText). */
function speedField(id) {
  const raw = $(id).value.trim();
  if (!raw) return undefined;
  if (raw.toLowerCase() === "auto") return "auto";
  return quantityText(raw, $(id).dataset.unit);
}

/** Upload a data file (``POST /api/datasets``, multipart) and queue its reconstruction
 *  (``POST /api/reconstructions`` with the ``dataset_id``); spacings and the speed of sound go
 *  out as typed (quantityText), read by the server. */
async function uploadAndReconstruct(ev) {
  ev.preventDefault();
  let uploadC;
  const file = $("upload-file").files[0];
  if (!file) { showError(new Error("Choose a file to upload.")); return; }
  const form = new FormData();
  form.append("file", file, file.name);
  form.append("format", $("upload-format").value);
  try {
    for (const name of ["dt", "dx", "dy"]) {
      if (!takesLoadOption(name)) continue; // not the chosen format's load option
      const v = quantityValue("upload-" + name, name, { optional: true });
      if (v !== undefined) form.append(name, v);
    }
    uploadC = speedField("upload-c");
    if (uploadC !== undefined && uploadC !== "auto") form.append("sound_speed", uploadC); // c: its deprecated name
    if ($("upload-force").checked) form.append("force", "true"); // c outside the plausible range
  } catch (err) { showError(err); return; }
  const key = $("upload-key").value.trim();
  if (key && takesLoadOption("key")) form.append("key", key);
  const axes = $("upload-axes").value.trim();
  if (axes && takesLoadOption("axes")) form.append("axes", axes);
  $("upload-start").disabled = true;
  $("upload-state").textContent = `Uploading ${file.name}…`;
  try {
    const ds = await apiJson("/api/datasets", { method: "POST", body: form });
    $("upload-state").textContent = `Uploaded as dataset ${shortId(ds.dataset_id)}${ds.shape ? " (" + ds.shape.join(" × ") + ")" : ""}; queueing…`;
    const resp = await apiFetch("/api/reconstructions", {
      method: "POST", json: { dataset_id: ds.dataset_id, method: $("upload-method").value,
                              params: Object.assign(uploadC === "auto" ? { sound_speed: "auto" } : {},
                                                    $("upload-force").checked ? { force: true } : {}) },
      headers: { "Idempotency-Key": newIdempotencyKey() },
    });
    const id = await jobIdFrom(resp);
    clearError();
    $("upload-state").textContent = `Reconstruction ${shortId(id)} queued.`;
    location.hash = "#/jobs/" + encodeURIComponent(id);
  } catch (err) {
    $("upload-state").textContent = "Not uploaded: " + (err.detail || err.message);
    showError(err);
  } finally {
    $("upload-start").disabled = false;
  }
}

async function cancelResultJob() {
  if (!resultJob) return;
  try {
    const j = await apiJson(`/api/jobs/${encodeURIComponent(resultJob)}/cancel`, { method: "POST" });
    clearError();
    if (j && j.state) setState($("result-state"), j.state);
    refreshJobs().catch(() => {});
  } catch (err) {
    showError(err);
  }
}

/* Reconstruction methods come from the server (GET /api/reconstructions/methods, i.e.
 * the registry fpscan.service.recon.methods): both method choices list them, and the reconstruct
 * form gets one field per option of any method, built from each option's value schema
 * (type, minimum/maximum, enum, unit, default); choosing a method shows only the options
 * it takes, starting from its own defaults. The speed of sound has its own field. */
let METHODS = null; // name -> {name, title, needs_grid, options: [{name, description, default, value_schema}], source, summary: [{key, label, title, id, format, flag, words, note, suffix, also}]}
const RECON_OWN_FIELDS = new Set(["sound_speed"]); // fields of the form itself, not generated

function methodOption(method, option) {
  const m = METHODS && METHODS[method];
  return m ? m.options.find((o) => o.name === option) : undefined;
}

/** The id of an option's field: recon-<its CLI flag or name with dashes> (max_iter: recon-max-iter). */
function optionFieldId(o) {
  const flag = o.value_schema && o.value_schema.flag;
  return "recon-" + (flag ? flag.replace(/^--/, "") : o.name.replace(/_/g, "-"));
}

function shownDefault(o) {
  if (o.default === null || o.default === undefined) return (o.value_schema && o.value_schema.derived) || "from the data";
  return String(o.default);
}

/** One field per option of any method (the first method's schema; the server keeps one rule per name). */
function buildOptionFields(list) {
  const box = $("recon-options");
  box.textContent = "";
  const seen = new Set();
  for (const m of list) {
    for (const o of m.options) {
      if (seen.has(o.name) || RECON_OWN_FIELDS.has(o.name)) continue;
      seen.add(o.name);
      const s = o.value_schema || {};
      const id = optionFieldId(o);
      const label = document.createElement("label");
      label.id = id + "-label";
      label.title = o.description;
      let input;
      const unit = s.unit && s.unit !== "1" && !s.quantity ? ` (${s.unit})` : "";  // a quantity shows it after the field
      if (s.type === "boolean") {
        input = document.createElement("input");
        input.type = "checkbox";
        label.appendChild(input);
        label.appendChild(document.createTextNode(` ${o.name} (${o.description})`));
      } else {
        if (s.enum) {
          input = document.createElement("select");
          for (const v of s.enum) {
            const opt = document.createElement("option");
            opt.value = v;
            opt.textContent = v;
            input.appendChild(opt);
          }
        } else {
          input = document.createElement("input");
          if (s.quantity) { // a length or time: a quantity field in its display unit (makeQuantityField)
            input.type = "text";
            input.size = 8;
          } else {
            input.type = "number";
            input.step = s.type === "integer" ? "1" : "any";
            if (s.minimum !== undefined) input.min = s.minimum;
            else if (s.exclusiveMinimum !== undefined) input.min = s.exclusiveMinimum;
            if (s.maximum !== undefined) input.max = s.maximum;
          }
          input.dataset.kind = s.type;
        }
        label.appendChild(document.createTextNode(`${o.name}${unit} `));
        label.appendChild(input);
        if (s.quantity && !s.enum) makeQuantityField(input, s.display_unit || s.unit);
      }
      input.id = id;
      input.dataset.option = o.name;
      box.appendChild(label);
    }
  }
}

async function buildMethodSelects() {
  const list = await apiJson("/api/reconstructions/methods");
  METHODS = {};
  for (const m of list) METHODS[m.name] = m;
  buildOptionFields(list);
  // the server's defaults (a scan: any sensor mask; an upload: a full lattice, the usual file)
  const defaultFor = (kind) => (list.find((m) => (m.default_for || []).includes(kind)) || list[0] || {}).name;
  for (const [id, preferred] of [["recon-method", defaultFor("points")], ["upload-method", defaultFor("grid")]]) {
    const sel = $(id);
    sel.textContent = "";
    for (const m of list) {
      const o = document.createElement("option");
      o.value = m.name;
      o.textContent = m.title;
      o.title = m.source;
      sel.appendChild(o);
    }
    sel.value = preferred in METHODS ? preferred : list[0].name;
  }
  // the "another medium" labels: the plausible speeds of the registry's one speed option
  // (sound_speed's value schema; fpscan.service.recon.methods.options.SpeedOptions)
  const speed = ((list[0] || {}).options || []).find((o) => o.name === "sound_speed");
  const number = speed && (speed.value_schema.anyOf || []).find((s) => s.type === "number");
  if (number) {
    for (const span of document.querySelectorAll(".speed-plausible")) span.textContent = `${number.minimum}–${number.maximum} ${speed.value_schema.unit || "m/s"}`;
  }
  renderReconOptions();
}

/* File formats come from the server (GET /api/formats, i.e. the registry fpscan.service.formats):
 * the upload form lists those an upload may have, in the server's order, the first chosen;
 * a job's downloads offer every export format (exportsOf). */
let FORMATS = null; // name -> the server's FormatInfo

async function buildFormatSelect() {
  const all = await apiJson("/api/formats");
  FORMATS = Object.fromEntries(all.map((f) => [f.name, f]));
  const list = all.filter((f) => f.upload);
  const sel = $("upload-format");
  sel.textContent = "";
  for (const f of list) {
    const o = document.createElement("option");
    o.value = f.name;
    o.textContent = f.title;
    sel.appendChild(o);
  }
  if (list.length) sel.value = list[0].name;
  // the upload's quantity fields (dt, dx, dy) in the unit their load option's schema shows
  for (const label of document.querySelectorAll("#upload-form [data-load-option]")) {
    const o = all.flatMap((f) => f.options || []).find((x) => x.name === label.dataset.loadOption);
    const s = (o && o.value_schema) || {};
    if (s.quantity) makeQuantityField(label.querySelector("input"), s.display_unit || s.unit);
  }
  sel.addEventListener("change", renderUploadOptions);
  renderUploadOptions();
}

/** Whether the chosen upload format declares the load option ``name`` (GET /api/formats: its
 *  ``options``, the format's own typed model, fpscan.service.formats.load_options). */
function takesLoadOption(name) {
  const f = (FORMATS || {})[$("upload-format").value];
  return !!f && (f.options || []).some((o) => o.name === name);
}

/** The upload form shows the fields of the chosen format's load options only. */
function renderUploadOptions() {
  for (const label of document.querySelectorAll("#upload-form [data-load-option]")) {
    label.hidden = !takesLoadOption(label.dataset.loadOption);
  }
}

/** The reconstruct form for the chosen method: its own defaults, only the options it takes. */
function renderReconOptions() {
  const method = $("recon-method").value;
  if (!METHODS || !METHODS[method]) return;
  for (const input of document.querySelectorAll("#recon-options [data-option]")) {
    const o = methodOption(method, input.dataset.option);
    $(input.id + "-label").hidden = !o;
    if (!o) { // not this method's: off and empty, as it is not sent
      if (input.type === "checkbox") input.checked = false;
      else if (input.tagName !== "SELECT") input.value = "";
      continue;
    }
    if (input.type === "checkbox") input.checked = !!o.default;
    else if (input.tagName === "SELECT") input.value = o.default !== null && o.default !== undefined ? o.default : input.options[0].value;
    else {
      input.value = "";
      input.placeholder = "empty = " + shownDefault(o);
    }
  }
}

/** The options the chosen method takes, as the form has them (an empty field: the method's default). */
function reconParams() {
  const method = $("recon-method").value;
  const params = {};
  for (const input of document.querySelectorAll("#recon-options [data-option]")) {
    const name = input.dataset.option;
    if (!methodOption(method, name)) continue;
    if (input.type === "checkbox") params[name] = input.checked;
    else if (input.tagName === "SELECT") params[name] = input.value;
    else if (input.value.trim() !== "") {
      const v = input.value.trim();
      // a quantity as text the server reads ("60 µm", "0.06 mm", a bare 60 in the field's unit), else a number
      params[name] = input.dataset.kind === "quantity" ? quantityText(v, input.dataset.unit) : Number(v);
    }
  }
  return params;
}

async function startRecon(ev) {
  ev.preventDefault();
  if (!resultJob) return;
  const params = reconParams();
  try {
    const c = speedField("recon-c");
    if (c !== undefined) params.sound_speed = c; // the HTTP name (c: its deprecated alias)
    if ($("recon-force").checked) params.force = true; // c outside the plausible range (fpscan.driver.units' rule)
  } catch (err) { showError(err); return; }
  const body = { scan_job_id: resultJob, method: $("recon-method").value, params };
  if ($("recon-unmix").checked) body.unmix = {}; // every wavelength: no wavelength choice
  else if (!$("recon-wavelength-label").hidden) {
    const w = $("recon-wavelength").value;
    body.wavelength = w === "all" ? "all" : Number(w);
  }
  $("recon-start").disabled = true;
  try {
    const resp = await apiFetch("/api/reconstructions", {
      method: "POST",
      json: body,
      headers: { "Idempotency-Key": newIdempotencyKey() },
    });
    const id = await jobIdFrom(resp);
    clearError();
    location.hash = "#/jobs/" + encodeURIComponent(id);
  } catch (err) {
    showError(err);
  } finally {
    $("recon-start").disabled = false;
  }
}

/* ------------------------------------------------------------------ start-up */

function updateTokenButton() {
  $("token-button").hidden = !getToken();  // "Sign out": only when signed in with a token
}

async function health() {
  try {
    const h = await apiJson("/api/health");
    $("server-status").textContent = `server: ${h.status}${h.version ? " v" + h.version : ""}`;
  } catch (err) {
    $("server-status").textContent = "server: unreachable";
  }
}

async function init() {
  takeTokenFromAddress();
  updateTokenButton();
  // the page's own quantity fields (the generated ones are made so as they are built)
  for (const input of document.querySelectorAll("input[data-unit]")) makeQuantityField(input, input.dataset.unit);
  $("login-form").addEventListener("submit", submitLogin);
  $("mask-kind").addEventListener("change", () => { renderMaskParams(); schedulePreview(0); });
  $("plan-form").addEventListener("input", () => schedulePreview());
  $("plan-form").addEventListener("submit", savePlan);
  $("scan-form").addEventListener("submit", startScan);
  $("scan-refresh").addEventListener("click", () => refreshScanLists().catch(showError));
  $("scan-plan").addEventListener("change", fillPreviewWavelengths);
  $("scan-pause").addEventListener("click", () => scanControl("pause"));
  $("scan-resume").addEventListener("click", () => scanControl("resume"));
  $("scan-abort").addEventListener("click", () => scanControl("abort"));
  $("jobs-filter").addEventListener("submit", (ev) => { ev.preventDefault(); refreshJobs().catch(showError); });
  $("jobs-state").addEventListener("change", () => { jobsBefore = null; refreshJobs().catch(showError); });
  $("jobs-kind").addEventListener("change", () => { jobsBefore = null; refreshJobs().catch(showError); });
  $("jobs-older").addEventListener("click", () => {
    jobsBefore = $("jobs-older").dataset.before || null;
    refreshJobs().catch(showError);
  });
  $("jobs-newest").addEventListener("click", () => { jobsBefore = null; refreshJobs().catch(showError); });
  $("result-slice").addEventListener("input", showSlice);
  $("recon-form").addEventListener("submit", startRecon);
  $("recon-method").addEventListener("change", renderReconOptions);
  $("result-cancel").addEventListener("click", cancelResultJob);
  $("upload-form").addEventListener("submit", uploadAndReconstruct);
  $("error-close").addEventListener("click", clearError);
  initPictureDialog();
  $("token-button").addEventListener("click", signOut);
  // sign in first when the server needs a token, so that no request of the page gets 401
  let state = null;
  try {
    state = await authState();
  } catch (err) {
    showError(err);
  }
  const needsLogin = Boolean(state && state.token_required && !state.authenticated);
  document.body.dataset.authChecked = needsLogin ? "login" : "open";  // the sign-in decision is made
  if (needsLogin) {
    const stale = Boolean(getToken());
    sessionStorage.removeItem(TOKEN_KEY);
    updateTokenButton();
    await showLogin(stale ? "The server refused the token this tab held (invalid bearer token). Sign in again." : "");
  }
  buildMaskSelect().catch(showError);
  buildMethodSelects().catch(showError);
  buildFormatSelect().catch(showError);
  window.addEventListener("hashchange", route);
  health();
  route();
  initStorage();  // after sign-in: its first requests carry the token
}

document.addEventListener("DOMContentLoaded", init);

/* ------------------------------------------------------------------ disk use and datasets */

/** Bytes with a binary prefix: 1536 -> "1.5 KiB". */
function fmtBytes(n) {
  return n === null || n === undefined || !isFinite(n) ? "unknown" : fmtQuantity(n, "B");  // one byte formatter
}

const STORAGE_PARTS = [["datasets_bytes", "Uploaded datasets"], ["results_bytes", "Reconstruction results"],
  ["scans_bytes", "Scan files"], ["exports_bytes", "Exports (IPASC)"], ["other_bytes", "Database and other"],
  ["total_bytes", "Total"], ["free_bytes", "Free on the disk"]];

/** Fill the disk-use table (GET /api/health: bytes by part) and the datasets table
 *  (GET /api/datasets), each dataset with a delete button (disabled while an active job
 *  reads it). */
async function refreshStorage() {
  const [h, datasets] = await Promise.all([apiJson("/api/health"), apiJson("/api/datasets")]);
  const disk = (h && h.disk) || {};
  const parts = $("storage-parts").querySelector("tbody");
  parts.replaceChildren();
  for (const [key, label] of STORAGE_PARTS) {
    if (!(key in disk)) continue;
    const tr = document.createElement("tr");
    tr.dataset.part = key.replace(/_bytes$/, "");
    tr.dataset.bytes = String(disk[key] ?? "");
    const th = document.createElement("th");
    th.scope = "row";
    th.textContent = label;
    const td = document.createElement("td");
    td.textContent = fmtBytes(disk[key]);
    tr.append(th, td);
    parts.append(tr);
  }
  const list = asList(datasets, "datasets");
  const body = $("storage-datasets").querySelector("tbody");
  body.replaceChildren();
  let total = 0;
  for (const d of list) {
    total += Number(d.size_bytes) || 0;
    const tr = document.createElement("tr");
    tr.dataset.datasetId = d.dataset_id;
    const jobs = (d.jobs || []).length;
    const cells = [shortId(d.dataset_id), d.name || "", d.format || "", fmtBytes(d.size_bytes),
      d.created ? new Date(d.created * 1000).toLocaleString() : "–", String(jobs) + (d.in_use ? " (active)" : "")];
    for (const c of cells) {
      const td = document.createElement("td");
      td.textContent = c;
      tr.append(td);
    }
    tr.firstChild.title = d.dataset_id;
    const td = document.createElement("td");
    const btn = document.createElement("button");
    btn.type = "button";
    btn.className = "danger storage-delete";
    btn.textContent = "Delete";
    btn.setAttribute("aria-label", `Delete dataset ${d.name || d.dataset_id}`);
    if (d.in_use) {
      btn.disabled = true;
      btn.title = "a queued, running or paused job reads this dataset";
    }
    btn.addEventListener("click", () => deleteDataset(d.dataset_id, d.name));
    td.append(btn);
    tr.append(td);
    body.append(tr);
  }
  $("storage-datasets-empty").hidden = list.length > 0;
  $("storage-datasets-total").textContent = list.length ? `(${list.length}, ${fmtBytes(total)})` : "";
}

/** DELETE /api/datasets/{id}, then refresh the storage section (the server's reason on refusal). */
async function deleteDataset(id, name) {
  if (!window.confirm(`Delete dataset ${name || shortId(id)} and its files?`)) return;
  try {
    const gone = await apiJson("/api/datasets/" + encodeURIComponent(id), { method: "DELETE" });
    $("storage-state").textContent = `Deleted dataset ${shortId(id)} (${fmtBytes(gone && gone.bytes_freed)} freed)`;
    clearError();
  } catch (err) {
    showError(err);
  }
  await refreshStorage().catch(showError);
}

function initStorage() {
  $("storage-refresh").addEventListener("click", () => refreshStorage().catch(showError));
  const onJobs = () => { if ((location.hash || "").startsWith("#/jobs")) refreshStorage().catch(showError); };
  window.addEventListener("hashchange", onJobs);  // an upload ends by opening its job: refreshed then
  onJobs();
}

