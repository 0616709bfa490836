// foveawarp live viewer page: one WebSocket at /ws; JSON text messages out, frames in
// (binary: [uint32 LE header length][header JSON][JPEG]) and JSON text messages of type "state" / "error".
"use strict";
(function () {
  const canvas = document.getElementById("view");
  const ctx = canvas.getContext("2d");
  const $ = (id) => document.getElementById(id);
  let ws = null;
  let state = null;          // last "state" message
  let renderW = 0;           // render size of the frames (side by side: the canvas is 2 x wide)
  let renderH = 0;
  let framesShown = 0;       // frames drawn: until the first, the canvas keeps the page's placeholder size
  let seq = 0;               // gaze sequence number; frames echo the seq they were rendered with
  const sentAt = new Map();  // seq -> performance.now() when sent (client-side round trip)
  let pendingGaze = null;
  let decoding = false;
  let nextFrame = null;      // newest undecoded frame (older ones are dropped)
  let recvTimes = [];
  let roundTrips = [];
  let lastHeader = null;
  let serverStats = {};
  let dragging = false;
  let lastDrag = null;
  const keys = new Set();

  function send(obj) {
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(obj));
  }

  function connect() {
    const proto = location.protocol === "https:" ? "wss" : "ws";
    ws = new WebSocket(proto + "://" + location.host + "/ws");
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { $("conn").textContent = "live"; $("conn").classList.add("on"); };
    ws.onclose = () => {
      $("conn").textContent = "disconnected"; $("conn").classList.remove("on");
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") onText(ev.data); else onFrame(ev.data);
    };
  }

  function onText(text) {
    let msg;
    try { msg = JSON.parse(text); } catch (e) { return; }
    if (msg.type === "state") applyState(msg);
    else if (msg.type === "error") showError(msg.message);
  }

  const errors = [];
  function showError(m) {
    errors.push(m);
    while (errors.length > 3) errors.shift();
    $("errors").textContent = errors.join("\n");
  }

  function onFrame(buf) {
    nextFrame = buf;                 // replace: a frame not yet decoded is dropped
    if (!decoding) decodeNext();
  }

  function decodeNext() {
    const buf = nextFrame;
    nextFrame = null;
    if (!buf) { decoding = false; return; }
    decoding = true;
    const dv = new DataView(buf);
    const n = dv.getUint32(0, true);
    let header;
    try { header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n))); } catch (e) { decodeNext(); return; }
    const blob = new Blob([new Uint8Array(buf, 4 + n)], { type: "image/jpeg" });
    createImageBitmap(blob).then((bmp) => {
      if (canvas.width !== header.width || canvas.height !== header.height) {
        canvas.width = header.width; canvas.height = header.height;
      }
      ctx.drawImage(bmp, 0, 0);
      bmp.close();
      renderW = header.render_width; renderH = header.render_height;
      framesShown += 1;
      frameShown(header);
      decodeNext();
    }, () => decodeNext());
  }

  function frameShown(h) {
    const now = performance.now();
    recvTimes.push(now);
    while (recvTimes.length && recvTimes[0] < now - 1000) recvTimes.shift();
    if (h.seq !== null && h.seq !== undefined && sentAt.has(h.seq)) {
      roundTrips.push(now - sentAt.get(h.seq));
      if (roundTrips.length > 200) roundTrips.shift();
      for (const k of sentAt.keys()) if (k <= h.seq) sentAt.delete(k);
    }
    lastHeader = h;
  }

  // -- gaze, orbit, fly ------------------------------------------------------------------------
  function toRender(ev) {
    // before the first frame the canvas is the page's placeholder size: map through the render size instead;
    // with neither known (no state yet) there is no gaze to send
    const r = canvas.getBoundingClientRect();
    const fw = framesShown ? canvas.width : renderW, fh = framesShown ? canvas.height : renderH;
    if (!fw || !fh || !r.width || !r.height) return null;
    let x = (ev.clientX - r.left) * fw / r.width;
    const y = (ev.clientY - r.top) * fh / r.height;
    if (renderW && x >= renderW) x -= renderW;   // side by side: both halves show the same view
    return [x, y];
  }

  canvas.addEventListener("mousemove", (ev) => {
    const g = toRender(ev);
    if (g) pendingGaze = g;
    if (dragging && lastDrag) {
      const dx = ev.clientX - lastDrag[0], dy = ev.clientY - lastDrag[1];
      if (dx || dy) send({ type: "orbit", dx: dx, dy: dy });
      lastDrag = [ev.clientX, ev.clientY];
    }
  });
  canvas.addEventListener("mousedown", (ev) => {
    if (ev.button === 0) { dragging = true; lastDrag = [ev.clientX, ev.clientY]; canvas.focus(); ev.preventDefault(); }
  });
  window.addEventListener("mouseup", () => { dragging = false; lastDrag = null; });

  function tick() {
    if (pendingGaze && (!state || state.gaze_source === "mouse")) {
      const x = Math.max(-renderW, Math.min(2 * renderW || 1e9, pendingGaze[0]));
      const y = Math.max(-renderH, Math.min(2 * renderH || 1e9, pendingGaze[1]));
      seq += 1;
      sentAt.set(seq, performance.now());
      if (sentAt.size > 500) sentAt.delete(sentAt.keys().next().value);
      send({ type: "gaze", x: x, y: y, seq: seq });
    }
    pendingGaze = null;
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);

  const KEYMAP = {
    KeyW: [1, 0, 0], ArrowUp: [1, 0, 0], KeyS: [-1, 0, 0], ArrowDown: [-1, 0, 0],
    KeyA: [0, -1, 0], ArrowLeft: [0, -1, 0], KeyD: [0, 1, 0], ArrowRight: [0, 1, 0],
    KeyE: [0, 0, 1], KeyQ: [0, 0, -1],
  };
  function typing(ev) { const t = ev.target; return t && (t.tagName === "INPUT" || t.tagName === "SELECT"); }
  window.addEventListener("keydown", (ev) => {
    if (typing(ev) || !(ev.code in KEYMAP)) return;
    keys.add(ev.code); ev.preventDefault();
  });
  window.addEventListener("keyup", (ev) => keys.delete(ev.code));
  window.addEventListener("blur", () => keys.clear());
  setInterval(() => {
    if (!keys.size) return;
    const v = [0, 0, 0];
    for (const k of keys) { const d = KEYMAP[k]; v[0] += d[0]; v[1] += d[1]; v[2] += d[2]; }
    const c = (a) => Math.max(-1, Math.min(1, a));
    send({ type: "fly", forward: c(v[0]), right: c(v[1]), up: c(v[2]) });
  }, 33);

  // -- controls ----------------------------------------------------------------------------------
  function applyState(s) {
    state = s;
    renderW = renderW || s.width; renderH = renderH || s.height;
    const sel = $("scene");
    if (sel.options.length !== s.scenes.length) {
      sel.innerHTML = "";
      for (const n of s.scenes) { const o = document.createElement("option"); o.value = n; o.textContent = n; sel.appendChild(o); }
    }
    sel.value = s.scene;
    for (const r of document.querySelectorAll("input[name=mode]")) r.checked = r.value === s.mode;
    for (const cb of document.querySelectorAll("input[data-overlay]")) cb.checked = !!s.overlays[cb.dataset.overlay];
    $("play").textContent = s.playing ? "pause path" : "play path";
    $("gazesrc-wrap").hidden = !s.has_trace;
    $("gazesrc").value = s.gaze_source;
    const k = s.knobs;
    const off = k.falloff_deg === null;
    $("falloff_off").checked = off;
    $("falloff_deg").disabled = off;
    if (!off) $("falloff_deg").value = k.falloff_deg;
    $("falloff_deg_out").textContent = off ? "null" : String(k.falloff_deg);
    for (const id of ["block", "ao_samples", "max_depth", "spp", "path_history"]) if (document.activeElement !== $(id)) $(id).value = k[id];
    for (const id of ["temporal", "dof", "indirect", "timing", "path", "path_filter", "path_filter_variance"]) $(id).checked = !!k[id];
    for (const el of document.querySelectorAll("small.range")) {
      const i = s.knob_info[el.dataset.range];
      if (i) el.textContent = "[" + i.lo + ", " + i.hi + "]";
    }
  }

  function setKnob(name, value) { send({ type: "set", knob: name, value: value }); }
  $("scene").addEventListener("change", (e) => send({ type: "scene", name: e.target.value }));
  for (const r of document.querySelectorAll("input[name=mode]")) {
    r.addEventListener("change", (e) => send({ type: "mode", value: e.target.value }));
  }
  for (const cb of document.querySelectorAll("input[data-overlay]")) {
    cb.addEventListener("change", (e) => { const m = { type: "overlay" }; m[cb.dataset.overlay] = e.target.checked; send(m); });
  }
  $("play").addEventListener("click", () => send({ type: "play", on: !(state && state.playing) }));
  $("reset").addEventListener("click", () => send({ type: "reset_camera" }));
  $("gazesrc").addEventListener("change", (e) => send({ type: "gaze_source", value: e.target.value }));
  $("resetstats").addEventListener("click", () => { roundTrips = []; send({ type: "reset_stats" }); });
  $("falloff_deg").addEventListener("input", (e) => { $("falloff_deg_out").textContent = e.target.value; });
  $("falloff_deg").addEventListener("change", (e) => setKnob("falloff_deg", Number(e.target.value)));
  $("falloff_off").addEventListener("change", (e) => setKnob("falloff_deg", e.target.checked ? null : Number($("falloff_deg").value)));
  for (const id of ["block", "ao_samples", "max_depth", "spp"]) {
    $(id).addEventListener("change", (e) => { const v = Number(e.target.value); if (Number.isInteger(v)) setKnob(id, v); else showError(id + " must be an integer"); });
  }
  for (const id of ["temporal", "dof", "indirect", "timing", "path", "path_filter", "path_filter_variance"]) {
    $(id).addEventListener("change", (e) => setKnob(id, e.target.checked));
  }
  $("path_history").addEventListener("change", (e) => { const v = Number(e.target.value); if (Number.isFinite(v)) setKnob("path_history", v); else showError("path_history must be a number"); });

  // -- stats -------------------------------------------------------------------------------------
  function pct(v) { return v === undefined || v === null ? "-" : (100 * v).toFixed(1) + " %"; }
  function ms(v) { return v === undefined || v === null ? "-" : Number(v).toFixed(2) + " ms"; }
  function quantile(a, q) { if (!a.length) return null; const s = a.slice().sort((x, y) => x - y); return s[Math.min(s.length - 1, Math.floor(q * s.length))]; }

  function renderStats() {
    const h = lastHeader, st = h ? h.stats : {};
    const rows = [
      ["fps (shown here)", recvTimes.length > 1 ? ((recvTimes.length - 1) * 1000 / (recvTimes[recvTimes.length - 1] - recvTimes[0])).toFixed(1) : "-"],
      ["fps (server)", st.fps !== undefined ? Number(st.fps).toFixed(1) : "-"],
      ["frame", h ? h.frame : "-"],
      ["size", h ? h.render_width + " x " + h.render_height : "-"],
      ["render + copy", ms(st.ms_frame)],
      ["jpeg encode", ms(st.ms_encode)],
    ];
    for (const k of Object.keys(st).sort()) {
      if (k.startsWith("ms_") && !["ms_frame", "ms_encode"].includes(k)) rows.push(["stage " + k.slice(3), ms(st[k])]);
    }
    rows.push(["sampling rate", pct(st.sampling_rate)]);
    rows.push(["cache hits", pct(st.cache_hit_rate)]);
    rows.push(["rays traced", st.rays_traced !== undefined ? Number(st.rays_traced).toLocaleString() : "-"]);
    if (st.paths_traced !== undefined) rows.push(["paths traced", Number(st.paths_traced).toLocaleString()]);
    rows.push(["gaze->frame p50 (srv)", ms(serverStats.latency_ms_p50)]);
    rows.push(["gaze->frame p95 (srv)", ms(serverStats.latency_ms_p95)]);
    rows.push(["gaze->frame p95 (msgs)", ms(serverStats.latency_msg_ms_p95)]);
    rows.push(["gaze->shown p50 (here)", ms(quantile(roundTrips, 0.5))]);
    rows.push(["gaze px", h ? h.gaze.map((v) => v.toFixed(0)).join(", ") : "-"]);
    rows.push(["device", state ? state.device : "-"]);
    rows.push(["encoder", state && state.encoder ? state.encoder.replace("Pillow ", "PIL ").split(",")[0] : "-"]);
    const box = $("stats");
    box.textContent = "";
    for (const [a, b] of rows) {
      const k = document.createElement("span"); k.className = "k"; k.textContent = a;
      const v = document.createElement("span"); v.className = "v"; v.textContent = b;
      box.appendChild(k); box.appendChild(v);
    }
  }
  setInterval(renderStats, 250);
  setInterval(() => {
    fetch("/stats.json", { cache: "no-store" }).then((r) => r.json()).then((s) => { serverStats = s; }, () => {});
  }, 1000);

  connect();
})();
