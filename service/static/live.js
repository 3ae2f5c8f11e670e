// colonlight web page, live mode: the camera or a video file, frame by frame through the /v1/stream WebSocket.
// One frame in flight: the next is captured when the enhanced one is back, so a slow server or link drops
// source frames instead of queueing them. Uses $, state and showError from app.js.
"use strict";

const live = { ws: null, media: null, running: false, masked: false, frames: 0, gammas: [], pending: null,
               sentAt: 0, startedAt: 0, lastSend: 0, rtts: [], grab: document.createElement("canvas"), timer: null };
const LIVE_PLOT_FRAMES = 300;
const LIVE_MAX_WIDTH = 960;  // frames wider than this are scaled down before they are sent

function setLiveStatus(status, note) {
  $("live-status").textContent = status;
  $("live-status").dataset.status = status;
  if (note !== undefined) $("live-source-note").textContent = note;
  const busy = ["connecting", "live", "ending"].includes(status);
  $("live-stop").disabled = !busy;
  $("live-camera").disabled = busy;
}

function setMode(mode) {
  document.body.classList.toggle("live", mode === "live");
  $("mode-clip").setAttribute("aria-selected", String(mode !== "live"));
  $("mode-live").setAttribute("aria-selected", String(mode === "live"));
  if (mode !== "live") liveStop();
}

function streamUrl() {
  return `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/v1/stream`;
}

async function liveStart(kind, file) {
  if (live.ws) {  // a new source replaces the running stream
    const old = live.ws;
    live.ws = null;
    if (old.readyState === WebSocket.OPEN) old.send(JSON.stringify({ type: "end" }));
  }
  liveRelease();
  showError("");
  state.key = $("apikey").value.trim() || state.key;
  const video = $("live-source");
  video.onended = null;
  try {
    if (kind === "camera") {
      if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) throw new Error("this browser gives no camera access here (it needs https or localhost)");
      live.media = await navigator.mediaDevices.getUserMedia({ video: { width: { ideal: 640 }, height: { ideal: 480 } }, audio: false });
      video.srcObject = live.media;
      setLiveStatus("connecting", "camera");
      await video.play();
    } else {  // loaded now, played once the stream is ready, so that no second of it passes unsent
      video.srcObject = null;
      await new Promise((resolve, reject) => {
        video.onloadeddata = resolve;
        video.onerror = () => reject(new Error(video.error && video.error.message ? video.error.message : "unsupported format"));
        video.src = URL.createObjectURL(file);
      });
      setLiveStatus("connecting", file.name);
      video.onended = () => liveEnd();
    }
  } catch (err) {
    setLiveStatus("failed");
    showError(kind === "camera" ? `No camera: ${err.message}` : `Cannot play ${file.name} here: ${err.message}`);
    liveRelease();
    return;
  }
  Object.assign(live, { frames: 0, gammas: [], pending: null, rtts: [], running: true, ending: false,
                        startedAt: performance.now(), lastSend: 0 });
  $("live-out").dataset.frames = "0";
  const ws = new WebSocket(streamUrl());
  ws.binaryType = "arraybuffer";
  live.ws = ws;
  ws.onopen = async () => {
    const start = { type: "start", method: $("method").value || undefined, format: "jpeg", quality: 85 };
    if (state.key) start.api_key = state.key;  // a browser cannot set headers on a WebSocket
    try {  // the form's content mask, if one is chosen: used instead of the detection, as for a clip
      const mask = await contentMaskForStream();
      if (mask) start.content_mask = mask;
      live.masked = Boolean(mask);
    } catch (err) { showError(err.message); ws.close(); return; }
    ws.send(JSON.stringify(start));
  };
  ws.onmessage = (e) => onLiveMessage(ws, e.data);
  ws.onclose = (e) => {
    if (live.ws !== ws) return;
    live.ws = null;
    live.running = false;
    liveRelease();
    if (e.code === 1000) setLiveStatus("done");
    else {
      setLiveStatus("failed");
      if (!$("error").textContent) showError(`The stream closed (${e.code}${e.reason ? ": " + e.reason : ""}).`);
    }
  };
}

function onLiveMessage(ws, data) {
  if (typeof data !== "string") { showLiveFrame(ws, data); return; }
  const msg = JSON.parse(data);
  if (msg.type === "ready") {
    setLiveStatus("live");
    $("live-note").textContent = `${msg.method}${msg.model ? " · " + msg.model.name : ""}`;
    const video = $("live-source");
    if (video.paused) video.play().catch((err) => showError(`Cannot play the file: ${err.message}`));
    sendNextFrame(ws);
  } else if (msg.type === "result") {
    live.pending = msg;
    if (!msg.bytes) { recordResult(msg); sendNextFrame(ws); }
  } else if (msg.type === "error") {
    showError(msg.message);  // a skipped frame, or why the server is about to close
    if (msg.code === "bad_frame") sendNextFrame(ws);
  } else if (msg.type === "end") {
    setLiveStatus("ending");
  }
}

async function showLiveFrame(ws, buffer) {
  const msg = live.pending;
  live.pending = null;
  const bitmap = await createImageBitmap(new Blob([buffer], { type: msg && msg.format === "png" ? "image/png" : "image/jpeg" }));
  const out = $("live-out");
  if (out.width !== bitmap.width || out.height !== bitmap.height) { out.width = bitmap.width; out.height = bitmap.height; }
  out.getContext("2d").drawImage(bitmap, 0, 0);
  bitmap.close();
  if (msg) recordResult(msg);
  sendNextFrame(ws);
}

function recordResult(msg) {
  live.frames += 1;
  live.rtts.push(performance.now() - live.sentAt);
  if (live.rtts.length > 50) live.rtts.shift();
  live.gammas.push(msg.gamma);
  if (live.gammas.length > LIVE_PLOT_FRAMES) live.gammas.shift();
  $("live-out").dataset.frames = String(live.frames);
  const seconds = (performance.now() - live.startedAt) / 1000;
  const rtt = [...live.rtts].sort((a, b) => a - b)[Math.floor(live.rtts.length / 2)];
  $("live-stats").textContent = `${live.frames} frames · ${(live.frames / seconds).toFixed(1)} fps · ` +
    `round trip ${rtt.toFixed(0)} ms (server ${msg.latency_ms.toFixed(0)} ms)`;
  $("live-gamma").textContent = msg.gamma === null ? "" : `frame ${msg.index}: γ = ${msg.gamma.toFixed(3)}${msg.seed ? " (seed)" : ""}`;
  drawLivePlot();
}

function sendNextFrame(ws) {
  if (live.ws !== ws || ws.readyState !== WebSocket.OPEN) return;
  const video = $("live-source");
  if (!live.running || video.ended) { liveEnd(); return; }
  const interval = 1000 / Math.max(1, Number($("live-fps").value) || Number($("live-fps").defaultValue));
  const wait = live.lastSend + interval - performance.now();
  if (wait > 0 || video.readyState < 2 || !video.videoWidth) {
    clearTimeout(live.timer);
    live.timer = setTimeout(() => sendNextFrame(ws), Math.max(wait, 10));
    return;
  }
  // a mask is of the source's frame size: frames are then sent at that size, never scaled down
  const scale = live.masked ? 1 : Math.min(1, LIVE_MAX_WIDTH / video.videoWidth);
  const grab = live.grab;
  grab.width = Math.round(video.videoWidth * scale);
  grab.height = Math.round(video.videoHeight * scale);
  grab.getContext("2d").drawImage(video, 0, 0, grab.width, grab.height);
  const time = video.currentTime;
  live.lastSend = performance.now();
  grab.toBlob(async (blob) => {
    if (live.ws !== ws || ws.readyState !== WebSocket.OPEN || !blob) return;
    const bytes = await blob.arrayBuffer();
    live.sentAt = performance.now();
    ws.send(JSON.stringify({ type: "frame", time }));
    ws.send(bytes);
  }, "image/jpeg", 0.9);
}

function liveEnd() {
  // Ask the server for what it still holds; it answers {"type": "end"} and closes with 1000.
  live.running = false;
  clearTimeout(live.timer);
  if (live.ws && live.ws.readyState === WebSocket.OPEN && !live.ending) {
    live.ending = true;
    setLiveStatus("ending");
    live.ws.send(JSON.stringify({ type: "end" }));
  }
}

function liveRelease() {
  clearTimeout(live.timer);
  if (live.media) { live.media.getTracks().forEach((t) => t.stop()); live.media = null; }
  const video = $("live-source");
  video.pause();
}

function liveStop() {
  if (live.ws) liveEnd();
  else liveRelease();
}

function drawLivePlot() {
  const svg = $("live-plot");
  svg.innerHTML = "";
  const W = 900, H = 160, T = 12, B = 12;
  const ys = live.gammas.map((g) => (g === null ? 1 : g));
  if (!ys.length) return;
  let y0 = Math.min(...ys, 1), y1 = Math.max(...ys, 1);
  const pad = Math.max((y1 - y0) * 0.1, 0.02);
  y0 -= pad; y1 += pad;
  const sx = (i) => (i / Math.max(ys.length - 1, 1)) * W;
  const sy = (y) => T + (1 - (y - y0) / (y1 - y0)) * (H - T - B);
  svg.appendChild(el("line", { x1: 0, x2: W, y1: sy(1), y2: sy(1), stroke: "#9aa5b1", "stroke-dasharray": "5 4" }));
  svg.appendChild(el("text", { x: 6, y: sy(1) - 4 }, "γ = 1"));
  const points = ys.map((y, i) => `${sx(i).toFixed(1)},${sy(y).toFixed(1)}`).join(" ");
  svg.appendChild(el("polyline", { id: "live-line", points, fill: "none", stroke: "#f2a65a", "stroke-width": 2 }));
  svg.dataset.points = String(ys.length);
}

function wireLive() {
  $("mode-clip").addEventListener("click", () => { setMode("clip"); history.replaceState(null, "", location.pathname); });
  $("mode-live").addEventListener("click", () => { setMode("live"); history.replaceState(null, "", "#live"); });
  $("live-camera").addEventListener("click", () => liveStart("camera"));
  $("live-file").addEventListener("change", (e) => { if (e.target.files.length) liveStart("file", e.target.files[0]); e.target.value = ""; });
  $("live-stop").addEventListener("click", liveStop);
  if (location.hash === "#live") setMode("live");
}

wireLive();
