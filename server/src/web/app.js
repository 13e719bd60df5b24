// Tessera's status page. Plain JavaScript, no build step: reads the JSON API, listens to
// server-sent events (/api/v1/events) and redraws only what changed.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else e.setAttribute(k, v);
  }
  for (const kid of kids) if (kid != null) e.append(kid);
  return e;
};

// --- API access (with the optional API token) ---------------------------------------------

let token = localStorage.getItem("tessera-token") || "";
$("#token").value = token;
$("#token").addEventListener("change", () => {
  token = $("#token").value.trim();
  localStorage.setItem("tessera-token", token);
  connect();
  loadAll();
});

function withToken(url) {
  if (!token) return url;
  return url + (url.includes("?") ? "&" : "?") + "access_token=" + encodeURIComponent(token);
}

async function api(path, options = {}) {
  const headers = options.headers || {};
  if (token) headers["Authorization"] = "Bearer " + token;
  const resp = await fetch(path, { ...options, headers });
  if (resp.status === 401) $("#token-box").hidden = false;
  return resp;
}

async function apiJson(path) {
  const resp = await api(path);
  if (!resp.ok) throw new Error(path + ": HTTP " + resp.status);
  return resp.json();
}

// Runs `fn` at most once per `ms` (trailing call kept): events can arrive by the hundred.
function throttle(fn, ms) {
  const timers = new Map();
  return (key, ...args) => {
    if (timers.has(key)) { timers.get(key).args = args; return; }
    const entry = { args };
    timers.set(key, entry);
    fn(...args);
    entry.args = null;
    setTimeout(() => {
      timers.delete(key);
      if (entry.args) fn(...entry.args);
    }, ms);
  };
}

// --- Jobs ------------------------------------------------------------------------------------

const jobs = new Map();   // id -> { data, node }

function fmtTime(unix) {
  return unix ? new Date(unix * 1000).toLocaleTimeString() : "-";
}

function fmtDuration(s) {
  if (!isFinite(s) || s < 0) return "-";
  if (s < 60) return s.toFixed(s < 10 ? 1 : 0) + " s";
  const m = Math.floor(s / 60);
  if (m < 60) return m + " min " + Math.round(s % 60) + " s";
  return Math.floor(m / 60) + " h " + (m % 60) + " min";
}

function jobNode(id) {
  let entry = jobs.get(id);
  if (entry) return entry;
  const node = el("div", { class: "job", "data-job-id": String(id) },
    el("div", { class: "job-head" },
      el("span", { class: "job-name" }),
      el("span", { class: "state" }),
      el("span", { class: "meta times" }),
      el("span", { class: "spacer" }),
      jobControlsNode(id),
      el("button", { class: "secondary cancel", text: "Cancel", onclick: () => cancelJob(id) })),
    el("div", { class: "error job-error", hidden: "" }),
    el("div", { class: "notice waiting-for", hidden: "" }),
    el("div", { class: "video", hidden: "" }),
    el("div", { class: "sequence", hidden: "" }),
    el("div", { class: "frames" }),
    el("details", { class: "log", open: "" },
      el("summary", { text: "Log" }),
      el("ol", { class: "log-lines" })));
  entry = { data: null, node, frames: new Map(), logSeq: 0, logBusy: false, logAgain: false };
  jobs.set(id, entry);
  $(".log", node).addEventListener("toggle", () => refreshLog(id, id));
  const list = $("#jobs");
  $(".empty", list)?.remove();
  // Newest first.
  const after = [...list.children].find((c) => Number(c.dataset.jobId) < id);
  list.insertBefore(node, after || null);
  return entry;
}

// `listed`: the job comes from the page's first listing. Jobs that had ended by then show their
// log closed and fetch it when opened, so a page over many old jobs does not fetch every log.
function renderJob(job, listed = false) {
  const entry = jobNode(job.id);
  if (!entry.data) {
    const ended = job.state === "done" || job.state === "failed" || job.state === "canceled";
    if (listed && ended) $(".log", entry.node).open = false;
    refreshLog(job.id, job.id);
  }
  // Answers can overtake each other: progress only ever grows.
  if (entry.data) {
    for (const f of job.frames) {
      const old = entry.data.frames.find((x) => x.index === f.index);
      if (old) {
        f.tiles_done = Math.max(f.tiles_done, old.tiles_done);
        f.samples_done = Math.max(f.samples_done || 0, old.samples_done || 0);
      }
    }
    job.samples_done = Math.max(job.samples_done || 0, entry.data.samples_done || 0);
  }
  entry.data = job;
  const n = entry.node;
  $(".job-name", n).textContent = "#" + job.id + " " + job.name;
  const st = $(".state", n);
  st.textContent = job.state;
  st.className = "state " + job.state;
  $(".times", n).textContent = jobTimes(job);
  $(".cancel", n).hidden = !(job.state === "queued" || job.state === "running" || job.state === "paused");
  renderJobControls(n, job);
  const err = $(".job-error", n);
  err.hidden = !job.error;
  err.textContent = job.error || "";
  renderWaiting(n, job);
  renderVideo(entry, job);
  if (isSequence(job)) renderSequence(entry, job);
  else for (const f of job.frames) renderFrame(entry, job, f);
}

// Progress counts samples (pixel-samples, pass by pass), not tiles: a frame in passes finishes
// its tiles only with its last pass. An older server's job has no sample counts: tiles then.
function jobWork(job) {
  if (job.samples_total > 0) return [job.samples_done, job.samples_total, "samples"];
  return [job.frames.reduce((a, f) => a + f.tiles_done, 0), job.frames.reduce((a, f) => a + f.tiles_total, 0), "tiles"];
}
function frameWork(f) {
  return f.samples_total > 0 ? [f.samples_done, f.samples_total] : [f.tiles_done, f.tiles_total];
}
function fmtCount(n) {
  if (n >= 1e9) return (n / 1e9).toFixed(1) + " G";
  if (n >= 1e6) return (n / 1e6).toFixed(1) + " M";
  if (n >= 1e3) return (n / 1e3).toFixed(1) + " k";
  return n.toFixed(0) + " ";
}
// Elapsed time, the rate of samples since the job started and the ETA it gives ("at most" under
// a noise target, whose total is an upper bound).
function jobTimes(job) {
  const now = Date.now() / 1000;
  const [done, total, unit] = jobWork(job);
  const elapsed = job.started_at ? (job.finished_at || now) - job.started_at : 0;
  const rate = elapsed > 0 ? done / elapsed : 0;
  let times = "submitted " + fmtTime(job.submitted_at) + " · elapsed " + fmtDuration(elapsed);
  if (job.state === "running") {
    times += " · ETA " + (rate > 0 ? (job.samples_total_is_bound ? "at most " : "") + fmtDuration((total - done) / rate) : "unknown");
  }
  if (rate > 0) times += " · " + fmtCount(rate) + unit + "/s";
  return times;
}

// --- Sequences and videos --------------------------------------------------------------------

// A job of several scene files, or of many cameras, is shown as a sequence: its counts, a grid
// of one small cell per frame (coloured by state; a click shows that frame) and one frame large
// (the latest merged unless one was chosen), instead of a block per frame.
const SEQUENCE_MIN_FRAMES = 9;
function isSequence(job) {
  return (job.scenes || 1) > 1 || job.frames.length >= SEQUENCE_MIN_FRAMES;
}

function frameState(f) {
  if (f.outputs.length) return "done";
  return f.tiles_done > 0 || (f.passes_done || 0) > 0 ? "rendering" : "queued";
}

function renderSequence(entry, job) {
  const box = $(".sequence", entry.node);
  box.hidden = false;
  if (!entry.seq) {
    entry.seq = { cells: [], selected: null, shown: null };
    box.append(
      el("div", { class: "seq-counts" }),
      el("div", { class: "seq-grid" }),
      el("figure", { class: "seq-view", hidden: "" },
        el("img", { class: "seq-frame", alt: "" }),
        el("figcaption", { class: "seq-caption" })));
  }
  const seq = entry.seq;
  const counts = { done: 0, rendering: 0, queued: 0 };
  const grid = $(".seq-grid", box);
  job.frames.forEach((f, i) => {
    const s = frameState(f);
    counts[s]++;
    let cell = seq.cells[i];
    if (!cell) {
      const index = f.index;
      cell = el("button", { type: "button", onclick: () => { seq.selected = index; renderSequence(entry, entry.data); } });
      grid.append(cell);
      seq.cells[i] = cell;
    }
    cell.className = "seq-cell " + s + (seq.selected === f.index ? " selected" : "");
    cell.dataset.state = s;
    cell.title = "frame " + f.index + (f.scene ? " · " + f.scene : "") + " · " + f.image_name + " · " + s;
  });
  // The server's counts once it gives them; until then, counted here.
  const fc = job.frame_counts;
  const c = fc && fc.done + fc.rendering + fc.queued === job.frames.length ? fc : counts;
  const counted = $(".seq-counts", box);
  counted.textContent = job.frames.length + " frames · " + c.done + " done · " + c.rendering + " rendering · " + c.queued + " queued";
  counted.dataset.done = String(c.done);
  const chosen = job.frames.find((f) => f.index === seq.selected)
    || [...job.frames].reverse().find((f) => f.outputs.length);
  const view = $(".seq-view", box);
  if (!chosen) { view.hidden = true; return; }
  view.hidden = false;
  // A merged frame's preview is its final picture (small, made once); a rendering frame's is
  // made from its tiles on each request.
  // A denoised job's merged frame is shown denoised (its `_denoised.png`).
  const picture = (job.denoise && denoisedOutput(chosen)) || { url: chosen.preview_url };
  const key = chosen.index + (chosen.outputs.length ? ":done" : ":" + chosen.tiles_done);
  if (seq.shown !== key) {
    seq.shown = key;
    $(".seq-frame", view).src = withToken(picture.url + "?t=" + Date.now());
  }
  const links = chosen.outputs.map((o) => o.name).join(", ");
  $(".seq-caption", view).textContent = "frame " + chosen.index + (chosen.scene ? " (" + chosen.scene + ")" : "") +
    " · " + chosen.image_name + " (" + chosen.width + "×" + chosen.height + ")" + (links ? " · " + links : " · " + frameState(chosen));
  view.dataset.frame = String(chosen.index);
}

// The job's video: its state, and once made, a player (<video>, or <img> for a GIF) and a link.
function renderVideo(entry, job) {
  const box = $(".video", entry.node);
  const v = job.video;
  if (!v) { box.hidden = true; return; }
  box.hidden = false;
  let line = $(".video-state", box);
  if (!line) { line = el("div", { class: "video-state" }); box.prepend(line); }
  line.textContent = "Video (" + v.kind.toUpperCase() + ", " + v.fps + " fps): " + v.state + (v.message ? " · " + v.message : "");
  box.dataset.state = v.state;
  if (v.state === "done" && v.url && box.dataset.url !== v.url) {
    box.dataset.url = v.url;
    const src = withToken(v.url);
    const name = v.url.split("/").pop();
    const player = v.kind === "gif"
      ? el("img", { class: "player", src, alt: "the job's video" })
      : el("video", { class: "player", src, controls: "", loop: "", preload: "metadata" });
    $(".player", box)?.remove();
    $(".video-link", box)?.remove();
    box.append(player, el("a", { class: "video-link", href: src, download: "job" + job.id + "-" + name, text: "download " + name }));
  }
}

function frameNode(entry, job, f) {
  let fr = entry.frames.get(f.index);
  if (fr) return fr;
  const node = el("div", { class: "frame", "data-frame": String(f.index) },
    el("div", { class: "frame-title" },
      el("span", { text: f.image_name + " (" + f.width + "×" + f.height + ")" }),
      el("span", { class: "progress-text" })),
    el("div", { class: "bar" }, el("div")),
    el("div", { class: "denoise-view", hidden: "" },
      el("span", { class: "denoise-label" }),
      el("button", { type: "button", class: "secondary denoise-toggle", onclick: () => toggleDenoised(entry, f.index) })),
    el("canvas", { class: "preview", width: String(f.width), height: String(f.height) }),
    el("div", { class: "links" }),
    el("div", { class: "tone", hidden: "" }));
  $(".frames", entry.node).append(node);
  fr = { node, shown: null, toneBuilt: false };
  entry.frames.set(f.index, fr);
  return fr;
}

function renderFrame(entry, job, f) {
  const fr = frameNode(entry, job, f);
  const [done, total] = frameWork(f);
  const pct = total ? Math.floor((100 * Math.min(done, total)) / total) : 0;
  let text = f.tiles_done + "/" + f.tiles_total + " tiles · " + pct + "%";
  // A frame in passes refines: say which pass is under way and the samples per pixel reached.
  if (!f.outputs.length && f.samples_total > 0) text = f.spp + " spp · " + text;
  if (f.passes_total > 1 && !f.outputs.length) text = "pass " + (f.pass || f.passes_done) + " of " + f.passes_total + " · " + text;
  $(".progress-text", fr.node).textContent = text;
  fr.node.dataset.passes = String(f.passes_done || 0);
  fr.node.dataset.percent = String(pct);
  $(".bar > div", fr.node).style.width = pct + "%";
  const links = $(".links", fr.node);
  const files = f.outputs.length ? f.outputs : (f.pass_outputs || []);
  links.replaceChildren(...files.map((o) => el("a", {
    href: withToken(o.url), download: o.name,
    text: f.outputs.length ? o.name : o.name + " (after pass " + f.passes_done + ")",
  })));
  renderDenoiseToggle(fr, job, f);
  if (f.outputs.length) {
    // The finished picture: the denoised PNG first for a denoised job, else (or when "raw" is
    // chosen) the first PNG output (tone-mapped for HDR frames).
    const png = (fr.view !== "raw" && denoisedOutput(f)) ||
      f.outputs.find((o) => o.name.toLowerCase().endsWith(".png") && !isDenoisedName(o.name));
    if (png && fr.shown !== png.url && !fr.toneActive) {
      fr.shown = png.url;
      draw(fr, png.url);
    }
    // Sliders only where the server can re-tone-map: an HDR frame with a float output.
    if (f.tonemap && f.tonemap_url && !fr.toneBuilt) buildTone(fr, job, f);
  } else if (job.denoise && fr.view !== "raw" && f.pass_denoised_url) {
    // The latest pass denoised, drawn again after each pass.
    const key = f.pass_denoised_url + "#" + f.passes_done;
    if (fr.shown !== key) { fr.shown = key; draw(fr, f.pass_denoised_url); }
  } else {
    // The live preview of the arrived tiles (also when coming back to it from the denoised pass).
    const back = fr.shown != null;
    fr.shown = null;
    if (back || f.tiles_done > 0 || f.passes_done > 0) refreshPreview(job.id + "/" + f.index, fr, f.preview_url);
  }
}

// --- Denoised previews -----------------------------------------------------------------------

// A frame of a job with denoise shows its denoised picture first (after each pass, then the
// finished frame's `_denoised.png`); a toggle shows the raw one instead, and back.
function isDenoisedName(name) { return /_denoised\.png$/i.test(name); }
function denoisedOutput(f) { return f.outputs.find((o) => isDenoisedName(o.name)); }

function renderDenoiseToggle(fr, job, f) {
  const box = $(".denoise-view", fr.node);
  if (!job.denoise) { box.hidden = true; return; }
  box.hidden = false;
  if (!fr.view) fr.view = "denoised";
  const has = f.outputs.length ? !!denoisedOutput(f) : !!f.pass_denoised_url;
  $(".denoise-label", box).textContent = fr.view === "raw" ? "Raw" :
    has ? "Denoised" : "Denoised (after the first pass; raw until then)";
  $(".denoise-toggle", box).textContent = fr.view === "raw" ? "Show denoised" : "Show raw";
  fr.node.dataset.view = fr.view;
}

function toggleDenoised(entry, index) {
  const fr = entry.frames.get(index);
  const f = entry.data && entry.data.frames.find((x) => x.index === index);
  if (!fr || !f) return;
  fr.view = fr.view === "raw" ? "denoised" : "raw";
  fr.toneActive = false;
  renderFrame(entry, entry.data, f);
}

// Pictures load asynchronously and can arrive out of order (a slow final PNG after a quick
// re-tone-mapped one): only the one asked for last is drawn.
function draw(fr, url) {
  const img = new Image();
  const seq = (fr.drawSeq = (fr.drawSeq || 0) + 1);
  img.onload = () => {
    if (seq !== fr.drawSeq) return;
    const c = $("canvas", fr.node);
    if (c.width !== img.naturalWidth) { c.width = img.naturalWidth; c.height = img.naturalHeight; }
    // Previews of large frames are smaller than the frame: drawn stretched to the canvas.
    c.getContext("2d").drawImage(img, 0, 0, c.width, c.height);
    fr.node.dataset.shown = url;
    fr.node.dataset.drawn = String((Number(fr.node.dataset.drawn) || 0) + 1);
  };
  img.src = withToken(url + (url.includes("?") ? "&" : "?") + "t=" + Date.now());
}

// The preview of a running frame: the server tone-maps what has arrived; at most every 400 ms.
const refreshPreview = throttle((fr, url) => { if (!fr.shown && !fr.toneActive) draw(fr, url); }, 400);

function buildTone(fr, job, f) {
  fr.toneBuilt = true;
  const t = f.tonemap;
  const box = $(".tone", fr.node);
  const gamma0 = parseFloat(t.gamma) || 2.2;
  const sliders = [
    ["key", "Key", 0.01, 1.0, 0.01, t.key],
    ["burn", "Burn %", 0, 20, 0.1, t.burn],
    ["saturation", "Saturation", 0, 2, 0.05, t.saturation],
    ["gamma", "Gamma", 1, 3, 0.05, gamma0],
  ];
  const values = {};
  const update = debounce(() => {
    fr.toneActive = true;
    const q = Object.entries(values).map(([k, v]) => k + "=" + v).join("&");
    const url = f.tonemap_url + "?" + q;
    draw(fr, url);
    const a = $("a.retoned", box);
    a.href = withToken(url);
  }, 150);
  const kids = [];
  for (const [name, label, min, max, step, value] of sliders) {
    values[name] = value;
    const out = el("span", { text: String(value) });
    const input = el("input", { type: "range", class: "tone-" + name, min: String(min), max: String(max), step: String(step), value: String(value) });
    input.addEventListener("input", () => { values[name] = input.value; out.textContent = input.value; update(); });
    kids.push(el("span", { text: label }), input, out);
  }
  box.replaceChildren(...kids, el("span"), el("a", { class: "retoned", href: "#", download: "retoned.png", text: "download this PNG" }));
  box.hidden = false;
}

function debounce(fn, ms) {
  let t = null;
  return () => { clearTimeout(t); t = setTimeout(fn, ms); };
}

async function loadJob(id) {
  try { renderJob(await apiJson("/api/v1/jobs/" + id)); } catch (e) { console.warn(e); }
  refreshLog(id, id);
}
const refreshJob = throttle((id) => loadJob(id), 700);

// --- Job logs (GET /api/v1/jobs/ID/log?after=SEQ: only the new lines) -------------------------

function logLine(e) {
  const where = [e.frame != null ? "frame " + e.frame : null, e.tile != null ? "tile " + e.tile : null,
    e.worker ? "on " + e.worker : null, e.seconds != null ? e.seconds.toFixed(3) + " s" : null]
    .filter(Boolean).join(" · ");
  return el("li", { class: "log-" + e.kind, "data-seq": String(e.seq) },
    el("span", { class: "log-at", text: fmtTime(e.at) }),
    el("span", { class: "log-kind", text: e.kind }),
    el("span", { class: "log-where", text: where }),
    el("span", { class: "log-message", text: e.message }));
}

async function loadLog(id) {
  const entry = jobs.get(id);
  if (!entry || !$(".log", entry.node).open) return;
  // One request at a time per job; a refresh asked for meanwhile runs after it.
  if (entry.logBusy) { entry.logAgain = true; return; }
  entry.logBusy = true;
  try {
    const log = await apiJson("/api/v1/jobs/" + id + "/log?after=" + entry.logSeq);
    const list = $(".log-lines", entry.node);
    const atBottom = list.scrollTop + list.clientHeight >= list.scrollHeight - 4;
    const fresh = log.events.filter((e) => e.seq > entry.logSeq);
    if (fresh.length) {
      list.append(...fresh.map(logLine));
      entry.logSeq = fresh[fresh.length - 1].seq;
      if (atBottom) list.scrollTop = list.scrollHeight;
    }
  } catch (e) {
    console.warn(e);
  } finally {
    entry.logBusy = false;
    if (entry.logAgain) { entry.logAgain = false; refreshLog(id, id); }
  }
}
const refreshLog = throttle((id) => loadLog(id), 500);

async function cancelJob(id) {
  const resp = await api("/api/v1/jobs/" + id + "/cancel", { method: "POST" });
  if (!resp.ok) alert((await resp.json()).error);
  loadJob(id);
}

// --- Job controls: pause, resume, requeue, delete, priority ----------------------------------

// The buttons and the priority field of a job's head; `renderJobControls` shows those that
// apply to its state.
function jobControlsNode(id) {
  const priority = el("input", { class: "priority", type: "number", step: "1", title: "Priority (higher first)" });
  priority.addEventListener("change", () => setPriority(id, priority));
  return el("span", { class: "job-controls" },
    el("label", { class: "meta priority-box", text: "priority " }, priority),
    el("button", { class: "secondary pause", text: "Pause", onclick: () => jobAction(id, "pause") }),
    el("button", { class: "secondary resume", text: "Resume", onclick: () => jobAction(id, "resume") }),
    el("button", { class: "secondary requeue", text: "Requeue", onclick: () => jobAction(id, "requeue") }),
    el("button", { class: "secondary delete", text: "Delete", onclick: () => deleteJob(id) }));
}

function renderJobControls(n, job) {
  const s = job.state;
  const ended = s === "done" || s === "failed" || s === "canceled";
  $(".pause", n).hidden = !(s === "queued" || s === "running");
  $(".resume", n).hidden = s !== "paused";
  $(".requeue", n).hidden = !(s === "failed" || s === "canceled");
  $(".delete", n).hidden = !ended;
  $(".priority-box", n).hidden = ended;
  const field = $(".priority", n);
  if (document.activeElement !== field) field.value = String(job.priority);
}

// POST /api/v1/jobs/ID/{pause,resume,requeue}: the answer is the job as it is now.
async function jobAction(id, action) {
  const resp = await api("/api/v1/jobs/" + id + "/" + action, { method: "POST" });
  if (!resp.ok) alert((await resp.json()).error);
  else renderJob(await resp.json());
  refreshLog(id, id);
}

async function setPriority(id, field) {
  const resp = await api("/api/v1/jobs/" + id, {
    method: "PATCH",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ priority: Number(field.value) }),
  });
  field.blur();
  if (!resp.ok) alert((await resp.json()).error);
  loadJob(id);
}

async function deleteJob(id) {
  if (!confirm("Delete job #" + id + " with its outputs? This cannot be undone.")) return;
  const resp = await api("/api/v1/jobs/" + id, { method: "DELETE" });
  if (!resp.ok) { alert((await resp.json()).error); return; }
  jobs.get(id)?.node.remove();
  jobs.delete(id);
}

// --- Workers ---------------------------------------------------------------------------------

let workers = [];
async function loadWorkers() {
  try { workers = (await apiJson("/api/v1/workers")).workers; renderWorkers(); } catch (e) { console.warn(e); }
}
const refreshWorkers = throttle(() => loadWorkers(), 1000);

function renderWorkers() {
  const body = $("#workers tbody");
  if (!workers.length) {
    body.replaceChildren(el("tr", {}, el("td", { colspan: "8", class: "empty", text: "No workers registered." })));
    return;
  }
  const now = Date.now() / 1000;
  body.replaceChildren(...workers.map((w) => el("tr", { "data-worker-id": String(w.id), "data-mode": w.mode || "active" },
    el("td", { text: w.name + " (" + w.threads + " threads)" + ((w.tags || []).length ? " · " + w.tags.join(", ") : "") }),
    el("td", { class: "state-" + w.state, text: w.state }),
    el("td", { class: "mode mode-" + (w.mode || "active"), text: w.mode || "active" }),
    el("td", { text: w.current_tile ? "job " + w.current_tile.job + " · frame " + w.current_tile.frame + " · tile " + w.current_tile.tile : "-" }),
    el("td", { class: "heartbeat-age", "data-at": String(w.last_heartbeat), text: fmtDuration(now - w.last_heartbeat) + " ago" }),
    el("td", { text: String(w.tiles_done) }),
    el("td", { text: String(w.failures) }),
    el("td", { class: "worker-actions" }, ...workerButtons(w)))));
}

// Drain (finish what it holds, take nothing new), disable (take nothing; its tiles go back to
// the queue) or enable a worker: the buttons its mode allows.
function workerButtons(w) {
  const mode = w.mode || "active";
  const button = (action, label, title) => el("button", {
    class: "secondary worker-" + action, type: "button", text: label, title,
    onclick: () => workerAction(w.id, action),
  });
  const out = [];
  if (mode === "active") out.push(button("drain", "Drain", "finish the tiles it holds, take no new one"));
  if (mode !== "disabled") out.push(button("disable", "Disable", "take nothing; the tiles it holds go back to the queue"));
  if (mode !== "active") out.push(button("enable", "Enable", "take work again"));
  return out;
}

async function workerAction(id, action) {
  const resp = await api("/api/v1/workers/" + id + "/" + action, { method: "POST" });
  if (!resp.ok) alert((await resp.json().catch(() => ({ error: "HTTP " + resp.status }))).error);
  loadWorkers();
}

// Why a job that has not ended makes no progress (no worker able to take it), from the server.
function renderWaiting(node, job) {
  const box = $(".waiting-for", node);
  box.hidden = !job.waiting_for;
  box.textContent = job.waiting_for ? "Waiting: " + job.waiting_for : "";
}

// The workers, and the jobs that have not ended (the newest 20), are looked at again every few
// seconds: a worker falling silent (lost, then forgotten) sends no event, and whether a worker
// can take a job changes with it.
setInterval(() => {
  refreshWorkers("w");
  const unended = [...jobs.entries()].filter(([, e]) => e.data && (e.data.state === "queued" || e.data.state === "running"));
  for (const [id] of unended.sort((a, b) => b[0] - a[0]).slice(0, 20)) refreshJob(id, id);
}, 3000);

// Heartbeat ages tick on the page (only their cells, so that a button being clicked stays);
// the data itself comes with events.
function tickWorkerAges() {
  const now = Date.now() / 1000;
  for (const td of document.querySelectorAll("#workers td.heartbeat-age")) {
    td.textContent = fmtDuration(now - Number(td.dataset.at)) + " ago";
  }
}
setInterval(tickWorkerAges, 1000);

// --- Live updates ----------------------------------------------------------------------------

let source = null;
function connect() {
  if (source) source.close();
  source = new EventSource(withToken("/api/v1/events"));
  const live = $("#live");
  source.onopen = () => { live.textContent = "live"; live.className = "live on"; };
  source.onerror = () => { live.textContent = "reconnecting"; live.className = "live off"; };
  source.addEventListener("tile", (ev) => {
    const e = JSON.parse(ev.data);
    const entry = jobs.get(e.job);
    if (!entry || !entry.data) { refreshJob(e.job, e.job); return; }
    const f = entry.data.frames.find((x) => x.index === e.frame);
    if (f && isSequence(entry.data)) {
      f.tiles_done = Math.max(f.tiles_done, e.tiles_done);
    } else if (f) {
      f.tiles_done = Math.max(f.tiles_done, e.tiles_done);
      const fr = frameNode(entry, entry.data, f);
      renderFrame(entry, entry.data, f);
      refreshPreview(e.job + "/" + e.frame, fr, f.preview_url);
    }
    refreshJob(e.job, e.job);
  });
  for (const name of ["job", "frame"]) {
    source.addEventListener(name, (ev) => { const e = JSON.parse(ev.data); refreshJob(e.job, e.job); });
  }
  source.addEventListener("workers", () => {
    refreshWorkers("w");
    // A worker came, went or changed mode: whether the waiting jobs can be served changed.
    for (const [id, entry] of jobs) if (entry.data && entry.data.waiting_for) refreshJob(id, id);
  });
  source.addEventListener("resync", () => loadAll());
}

async function loadAll() {
  try {
    const resp = await api("/api/v1/jobs");
    if (resp.status === 401) { showTokenNeeded(); return; }
    if (!resp.ok) throw new Error("/api/v1/jobs: HTTP " + resp.status);
    const list = await resp.json();
    showJobsEmpty();
    for (const job of list.jobs.slice().reverse()) renderJob(job, true);
  } catch (e) { console.warn(e); }
  loadWorkers();
}

// A farm with an API token answers 401 until the page has it: the jobs list says so (and where
// to enter it) instead of "No jobs yet.".
function showTokenNeeded() {
  const list = $("#jobs");
  if (jobs.size) return;
  const text = token
    ? "The API token entered was refused, so no job can be shown: enter the farm's API token " +
      "(the one tessera-server was started with, --api-token or TESSERA_API_TOKEN) in the API token box at the top right."
    : "This farm needs its API token to show its jobs: enter it in the API token box at the top right " +
      "(the one tessera-server was started with, --api-token or TESSERA_API_TOKEN).";
  list.replaceChildren(el("p", { class: "empty token-needed", text }));
  $("#token-box").hidden = false;
  $("#token").focus();
}

// The jobs list once the server answered: "No jobs yet." while it has none.
function showJobsEmpty() {
  const list = $("#jobs");
  if (!jobs.size) list.replaceChildren(el("p", { class: "empty", text: "No jobs yet." }));
}

// --- Submitting ------------------------------------------------------------------------------

const ARCHIVE = /\.(tar|tar\.gz|tgz|zip)$/i;
const SCENE = /\.(xml|json)$/i;

// A file's path inside the upload: relative to the chosen folder, or its plain name.
function relPath(file) {
  const p = file.webkitRelativePath || file.name;
  const parts = p.split("/");
  return parts.length > 1 ? parts.slice(1).join("/") : p;
}

$("#submit").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const errBox = $("#submit-error"), okBox = $("#submit-ok");
  errBox.hidden = true; okBox.hidden = true;
  const files = [...$("#files").files, ...$("#folder").files];
  if (!files.length) { showError("Choose a scene file (and its assets), a folder or a bundle first."); return; }
  const form = new FormData();
  if (files.length === 1 && ARCHIVE.test(files[0].name)) {
    form.append("bundle", files[0], files[0].name);
  } else {
    const scenes = files.filter((f) => SCENE.test(f.name));
    if (!scenes.length) { showError("No scene file (.xml or .json) among the chosen files."); return; }
    scenes.sort((a, b) => relPath(a).split("/").length - relPath(b).split("/").length);
    const scene = scenes[0];
    form.append("scene", scene, relPath(scene));
    for (const f of files) if (f !== scene) form.append("asset", f, relPath(f));
  }
  for (const [id, field] of [["priority", "priority"], ["tile-size", "tile_size"], ["samples", "samples"],
    ["pass-samples", "pass_samples"], ["noise-target", "noise_target"], ["video", "video"], ["fps", "fps"]]) {
    const v = $("#" + id).value.trim();
    if (v !== "" && !(field === "priority" && v === "0")) form.append(field, v);
  }
  if ($("#denoise").checked) form.append("denoise", "true");
  const button = $("#submit-button");
  button.disabled = true;
  try {
    const resp = await api("/api/v1/jobs", { method: "POST", body: form });
    const body = await resp.json().catch(() => ({ error: "HTTP " + resp.status }));
    if (!resp.ok) { showError(body.error, body.problems); return; }
    okBox.textContent = "Job #" + body.id + " accepted: " + body.frames.length + " frame(s), " +
      body.frames.reduce((a, f) => a + f.tiles_total, 0) + " tiles.";
    okBox.hidden = false;
    renderJob(body);
    $("#files").value = ""; $("#folder").value = "";
  } catch (e) {
    showError("The upload failed: " + e.message);
  } finally {
    button.disabled = false;
  }
});

function showError(message, problems) {
  const box = $("#submit-error");
  box.replaceChildren(el("strong", { text: message }));
  for (const p of problems || []) {
    const where = [p.file, p.line != null ? "line " + p.line : null, p.element ? "<" + p.element + ">" : null].filter(Boolean).join(", ");
    box.append(el("div", { class: "problem", text: where + ": " + p.message }));
  }
  box.hidden = false;
}

connect();
loadAll();
