// colonlight web page: drop a clip, watch the job, compare original and enhanced, plot the gammas.
// Plain JS, no build step and no CDN: it only talks to this server's /v1 API.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { key: localStorage.getItem("colonlight-api-key") || "", job: null, gammas: null, authRequired: false };

function headers() {
  return state.key ? { "X-API-Key": state.key } : {};
}

async function api(path, options = {}) {
  const resp = await fetch(path, { ...options, headers: { ...headers(), ...(options.headers || {}) } });
  if (!resp.ok) {
    let message = `${resp.status} ${resp.statusText}`;
    try { message = (await resp.json()).message || message; } catch (_) { /* not JSON */ }
    const err = new Error(message);
    err.status = resp.status;
    throw err;
  }
  return resp;
}

function showError(message) {
  const el = $("error");
  el.textContent = message || "";
  el.hidden = !message;
}

function setStatus(status, detail) {
  $("status").textContent = status;
  $("status").dataset.status = status;
  if (detail !== undefined) $("detail").textContent = detail;
}

function setBar(fraction) {
  $("bar-fill").style.width = `${Math.max(0, Math.min(1, fraction || 0)) * 100}%`;
}

async function loadInfo() {
  try {
    const info = await (await api("/v1/info")).json();
    state.authRequired = info.auth_required;
    $("key-row").hidden = !info.auth_required;
    const select = $("method");
    select.innerHTML = "";
    for (const m of info.methods) {
      const opt = document.createElement("option");
      opt.value = opt.textContent = m;
      if (m === info.defaults.method) opt.selected = true;
      select.appendChild(opt);
    }
    $("fps").value = info.defaults.fps;  // the server's default and bound (colonlight/limits.py), not copies
    $("fps").max = info.limits.max_fps;
    $("live-fps").value = $("live-fps").defaultValue = info.defaults.fps || $("live-fps").max;
    $("limits").textContent = `any video FFmpeg reads, up to ${info.limits.max_upload_mb} MiB`;
    showError("");
  } catch (err) {
    if (err.status === 401) {
      $("key-row").hidden = false;
      showError("This server needs an API key: type it in the API key field, then drop a clip.");
    } else {
      showError(`Cannot reach the server: ${err.message}`);
    }
  }
}

function contentMaskForStream() {
  // The content mask chosen in the form, for a /v1/stream start message's "content_mask": {name, data: the
  // file's bytes in base64}, or null when none is chosen. A WebSocket message is JSON, hence base64.
  const file = $("mask").files[0];
  if (!file) return Promise.resolve(null);
  return new Promise((resolve, reject) => {
    const reader = new FileReader();
    reader.onload = () => resolve({ name: file.name, data: String(reader.result).split(",", 2)[1] || "" });  // data:...;base64,<data>
    reader.onerror = () => reject(new Error(`cannot read the content mask ${file.name}`));
    reader.readAsDataURL(file);
  });
}

function upload(file) {
  // XMLHttpRequest, not fetch: it reports upload progress.
  return new Promise((resolve, reject) => {
    const form = new FormData();
    form.append("method", $("method").value || "rnn");
    if ($("fps").value !== "") form.append("fps", $("fps").value);  // else the server's default
    const mask = $("mask").files[0];  // optional: the scope's content mask, used instead of the detection
    if (mask) form.append("content_mask", mask, mask.name);
    form.append("file", file, file.name);
    const xhr = new XMLHttpRequest();
    xhr.open("POST", "/v1/jobs");
    for (const [k, v] of Object.entries(headers())) xhr.setRequestHeader(k, v);
    xhr.upload.onprogress = (e) => {
      if (e.lengthComputable) { setBar(e.loaded / e.total); setStatus("uploading", `${(e.loaded / 1048576).toFixed(1)} MiB sent`); }
    };
    xhr.onload = () => {
      let body = {};
      try { body = JSON.parse(xhr.responseText); } catch (_) { /* keep {} */ }
      if (xhr.status === 202) resolve(body);
      else reject(new Error(body.message || `upload failed: HTTP ${xhr.status}`));
    };
    xhr.onerror = () => reject(new Error("upload failed: the connection was lost"));
    xhr.send(form);
  });
}

async function poll(jobId) {
  for (;;) {
    const job = await (await api(`/v1/jobs/${jobId}`)).json();
    state.job = job;
    const total = job.frames_total ? ` / ${job.frames_total}` : "";
    setStatus(job.status, `${job.frames_done}${total} frames${job.note ? " · " + job.note : ""}`);
    setBar(job.progress || 0);
    if (job.status === "succeeded" || job.status === "failed") return job;
    await new Promise((r) => setTimeout(r, 500));
  }
}

async function mediaUrl(path) {
  // Without a key the browser streams (and seeks with range requests); with one it must fetch with the header.
  if (!state.key) return path;
  const blob = await (await api(path)).blob();
  return URL.createObjectURL(blob);
}

function showOriginal(file) {
  const video = $("original");
  $("original-note").textContent = "";
  video.onerror = () => {
    $("original-note").textContent = `(this browser cannot play ${file.name.split(".").pop()} files; the enhanced clip is H.264)`;
  };
  video.src = URL.createObjectURL(file);
}

async function showResults(job) {
  $("results").hidden = false;
  const video = $("enhanced");
  video.src = await mediaUrl(job.links.video);
  $("enhanced-note").textContent = `H.264 at ${job.options.fps || "source"} fps`;
  state.gammas = await (await api(job.links.gammas)).json();
  drawPlot(state.gammas);
  const links = [["video", job.links.video], ["gammas.json", job.links.gammas]];
  if (job.options.frames) links.push(["frames.zip", job.links.frames]);
  $("links").innerHTML = "";
  for (const [label, href] of links) {
    const a = document.createElement("a");
    a.textContent = label;
    a.href = href;
    if (state.key) a.onclick = async (e) => { e.preventDefault(); window.open(await mediaUrl(href)); };
    $("links").appendChild(a);
  }
}

const SVG = "http://www.w3.org/2000/svg";
function el(name, attrs, text) {
  const node = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}

function niceStep(range, ticks) {
  const raw = range / ticks, mag = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw) || raw;
}

function drawPlot(gammas) {
  const svg = $("plot");
  svg.innerHTML = "";
  const W = 900, H = 260, L = 52, R = 14, T = 24, B = 34;
  const frames = gammas.frames.filter((f) => f.gamma !== null && f.gamma !== undefined);
  if (!frames.length) {
    svg.appendChild(el("text", { x: W / 2, y: H / 2, "text-anchor": "middle" }, `${gammas.method} has no per-frame gamma`));
    return;
  }
  const xs = frames.map((f) => f.time_s), ys = frames.map((f) => f.gamma);
  const x0 = Math.min(...xs), x1 = Math.max(...xs, x0 + 1e-6);
  let y0 = Math.min(...ys, 1), y1 = Math.max(...ys, 1);
  const pad = Math.max((y1 - y0) * 0.1, 0.02);
  y0 -= pad; y1 += pad;
  const sx = (x) => L + ((x - x0) / (x1 - x0)) * (W - L - R);
  const sy = (y) => T + (1 - (y - y0) / (y1 - y0)) * (H - T - B);
  const grid = "#2c333d";
  const ystep = niceStep(y1 - y0, 5);
  for (let y = Math.ceil(y0 / ystep) * ystep; y <= y1 + 1e-9; y += ystep) {
    svg.appendChild(el("line", { x1: L, x2: W - R, y1: sy(y), y2: sy(y), stroke: grid }));
    svg.appendChild(el("text", { x: L - 6, y: sy(y) + 4, "text-anchor": "end" }, y.toFixed(ystep < 0.1 ? 2 : 1)));
  }
  const xstep = niceStep(x1 - x0, 8);
  for (let x = Math.ceil(x0 / xstep) * xstep; x <= x1 + 1e-9; x += xstep) {
    svg.appendChild(el("line", { x1: sx(x), x2: sx(x), y1: T, y2: H - B, stroke: grid }));
    svg.appendChild(el("text", { x: sx(x), y: H - B + 16, "text-anchor": "middle" }, `${+x.toFixed(2)} s`));
  }
  svg.appendChild(el("line", { x1: L, x2: W - R, y1: sy(1), y2: sy(1), stroke: "#9aa5b1", "stroke-dasharray": "5 4" }));
  svg.appendChild(el("text", { x: L - 6, y: 15, "text-anchor": "end" }, "γ"));
  svg.appendChild(el("text", { x: W - R, y: 15, "text-anchor": "end" },
    `${gammas.method}${gammas.model ? " · " + gammas.model.name : ""} · ${frames.length} frames`));
  const points = frames.map((f) => `${sx(f.time_s).toFixed(1)},${sy(f.gamma).toFixed(1)}`).join(" ");
  svg.appendChild(el("polyline", { id: "gamma-line", points, fill: "none", stroke: "#f2a65a", "stroke-width": 2.5 }));
  svg.appendChild(el("line", { id: "playhead", x1: L, x2: L, y1: T, y2: H - B, stroke: "#e8ecf1", "stroke-width": 1.5 }));
  svg.dataset.points = String(frames.length);
  state.plot = { sx, frames };
}

function onTime() {
  if (!state.plot) return;
  const t = $("enhanced").currentTime;
  const x = state.plot.sx(t);
  const head = $("playhead");
  head.setAttribute("x1", x); head.setAttribute("x2", x);
  const f = state.plot.frames.reduce((best, f) => (Math.abs(f.time_s - t) < Math.abs(best.time_s - t) ? f : best));
  $("gamma-now").textContent = `frame ${f.index}, t = ${f.time_s.toFixed(2)} s, γ = ${f.gamma.toFixed(3)}`;
}

async function start(file) {
  showError("");
  state.key = $("apikey").value.trim() || state.key;
  if (state.key) localStorage.setItem("colonlight-api-key", state.key);
  $("progress").hidden = false;
  $("results").hidden = true;
  $("links").innerHTML = "";
  $("filename").textContent = file.name;
  setBar(0);
  setStatus("uploading", "");
  showOriginal(file);
  try {
    const job = await upload(file);
    history.replaceState(null, "", `#job=${job.id}`);
    const done = await poll(job.id);
    if (done.status === "failed") { showError(done.error); return; }
    await showResults(done);
  } catch (err) {
    setStatus("failed");
    showError(err.message);
  }
}

function wire() {
  const drop = $("drop");
  drop.addEventListener("dragover", (e) => { e.preventDefault(); drop.classList.add("over"); });
  drop.addEventListener("dragleave", () => drop.classList.remove("over"));
  drop.addEventListener("drop", (e) => {
    e.preventDefault();
    drop.classList.remove("over");
    if (e.dataTransfer.files.length) start(e.dataTransfer.files[0]);
  });
  $("file").addEventListener("change", (e) => { if (e.target.files.length) start(e.target.files[0]); });
  $("apikey").value = state.key;
  $("apikey").addEventListener("change", () => {
    state.key = $("apikey").value.trim();
    localStorage.setItem("colonlight-api-key", state.key);
    loadInfo();
  });
  $("enhanced").addEventListener("timeupdate", onTime);
  $("enhanced").addEventListener("seeked", onTime);
  $("play-both").addEventListener("click", () => {
    const a = $("original"), b = $("enhanced");
    const t = b.currentTime;
    if (a.readyState > 0) a.currentTime = Math.min(t, a.duration || t);
    [a, b].forEach((v) => v.play().catch(() => {}));
  });
  // Keep the original beside the enhanced clip when the latter is sought or paused.
  $("enhanced").addEventListener("seeked", () => { const a = $("original"); if (a.readyState > 0) a.currentTime = $("enhanced").currentTime; });
  $("enhanced").addEventListener("pause", () => $("original").pause());
}

wire();
loadInfo();
