// ferrosa's operator console: the page side of `ferrosa serve`. Everything it shows
// comes from the server's event stream (/api/events), replayed from the start when the
// page loads, so every open page shows the same session. Text from the robot or the
// model is only ever set as text, never as markup.
"use strict";

const $ = (id) => document.getElementById(id);
const runs = new Map();        // run → {bubble, raw, calls: Map, answered}
const approvals = new Map();   // id → {name, arguments, timeout_s}
let view = null;
let trail = [];
let places = [];               // the robot's places, from /api/memory
let drawing = false;
let shownApproval = null;
let live = false;              // past the replay: answers may be spoken
let rec = null;                // the recording in progress
// The dialog's buttons wait this long after it shows a call, so a second click meant
// for one call never answers the next.
const SETTLE_MS = 800;

async function post(path, body) {
  const r = await fetch(path, {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body || {}),
  });
  const data = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(data.error || `HTTP ${r.status}`);
  return data;
}

function notice(text) {
  $("notice").textContent = text || "";
}

function el(tag, cls, text) {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
}

function scrollDown(list) {
  list.scrollTop = list.scrollHeight;
}

// ---- the answer as it is written ------------------------------------------------

// The text of the answer tool's call so far, decoded from the JSON being written; the
// text itself when the model writes prose; null while it writes another call.
function answerSoFar(raw) {
  const m = raw.match(/"name"\s*:\s*"reply"\s*,\s*"arguments"\s*:\s*\{\s*"text"\s*:\s*"/);
  if (m) return partialString(raw.slice(m.index + m[0].length));
  if (!/^\s*(<|\[|\{)/.test(raw)) return raw;
  return null;
}

// A JSON string's content up to its closing quote or the end of what is written.
function partialString(s) {
  let out = "";
  for (let i = 0; i < s.length; i++) {
    const c = s[i];
    if (c === '"') break;
    if (c !== "\\") { out += c; continue; }
    const n = s[i + 1];
    if (n === undefined) break;
    const simple = { n: "\n", t: "\t", r: "", b: "", f: "", '"': '"', "\\": "\\", "/": "/" };
    if (n in simple) { out += simple[n]; i++; continue; }
    if (n === "u") {
      const hex = s.slice(i + 2, i + 6);
      if (hex.length < 4) break;
      out += String.fromCharCode(parseInt(hex, 16));
      i += 5;
      continue;
    }
    i++;
  }
  return out;
}

// ---- calls as the operator follows them -------------------------------------------

// One line per call in the answer's bubble ("→ ros_topic_echo /turtle1/pose"), with a
// spinner and its time while it runs, its time or its refusal once it is back; the
// arguments and results in full are in the trace beside.
const FRAMES = "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏";
const running = new Set();     // {took, since} of the calls not back yet
let ticker = null;

function argsLine(args) {
  const entries = Object.entries(args || {});
  const value = (v) => (typeof v === "string" ? v : JSON.stringify(v));
  if (entries.length === 1) return ` ${value(entries[0][1])}`;
  return entries.map(([k, v]) => ` ${k}=${value(v)}`).join("");
}

function callLine(r, d) {
  const li = el("li", "step");
  const took = el("span", "took muted", "");
  li.append(el("span", "call", `→ ${d.name}${argsLine(d.arguments)}`), " ", took);
  r.steps.append(li);
  const line = { li, took, since: performance.now(), progress: "" };
  if (d.decision.decision === "refused") {
    li.classList.add("refused");
    took.textContent = `refused: ${d.decision.reason || ""}`;
  } else {
    running.add(line);
    if (!ticker) ticker = setInterval(tick, 100);
  }
  return line;
}

function tick() {
  const frame = FRAMES[Math.floor(performance.now() / 100) % FRAMES.length];
  for (const line of running) {
    const secs = ((performance.now() - line.since) / 1000).toFixed(1);
    line.took.textContent = line.progress ? `${frame} ${line.progress} · ${secs} s` : `${frame} ${secs} s`;
  }
  if (running.size === 0) {
    clearInterval(ticker);
    ticker = null;
  }
}

function callDone(line, d) {
  running.delete(line);
  if (line.li.classList.contains("refused")) return;
  const took = d.ms < 100 ? `${Math.round(d.ms)} ms` : `${(d.ms / 1000).toFixed(1)} s`;
  line.took.textContent = d.ok ? `· ${took}` : `✗ ${took}: ${(d.output && d.output.error) || "failed"}`;
  if (!d.ok) line.li.classList.add("failed");
}

// ---- conversation and trace ------------------------------------------------------

function onRequest(d) {
  const list = $("messages");
  list.append(el("li", "user", d.text));
  const bubble = el("li", "agent writing");
  bubble.dataset.run = d.run;
  const steps = el("ul", "steps");
  const text = el("div", "text", "…");
  bubble.append(steps, text);
  list.append(bubble);
  runs.set(d.run, { bubble, steps, text, raw: "", calls: new Map(), lines: new Map(), answered: false });
  scrollDown(list);
  setBusy(true);
}

function traceItem(cls) {
  const li = el("li", cls);
  $("trace").append(li);
  scrollDown($("trace"));
  return li;
}

function onAgent(d) {
  const r = runs.get(d.run);
  if (!r) return;
  switch (d.event) {
    case "step":
      r.raw = "";
      traceItem("step").textContent =
        `run ${d.run} · step ${d.step} · ${d.prompt_tokens} prompt tokens (${d.reused_tokens} cached) · ${d.tools.length} tools offered`;
      break;
    case "token": {
      r.raw += d.text;
      const shown = answerSoFar(r.raw);
      if (shown !== null && !r.answered) r.text.textContent = shown || "…";
      break;
    }
    case "tool_call": {
      const li = traceItem("call");
      li.dataset.key = `${d.run}/${d.step}/${d.index}`;
      li.dataset.name = d.name;
      const details = el("details");
      const summary = el("summary");
      const decision = d.decision.decision;
      li.dataset.decision = decision;
      summary.append(el("code", "name", d.name), " ",
        el("span", `decision ${decision}`, decision), " ", el("span", "ms muted", ""));
      details.append(summary, el("div", "muted", "arguments"),
        el("pre", "arguments", JSON.stringify(d.arguments, null, 1)));
      if (d.decision.reason) details.append(el("div", "muted", "reason"), el("pre", "reason", d.decision.reason));
      li.append(details);
      r.calls.set(li.dataset.key, li);
      if (d.name !== "reply") r.lines.set(li.dataset.key, callLine(r, d));
      break;
    }
    case "tool_progress": {
      const line = r.lines.get(`${d.run}/${d.step}/${d.index}`);
      if (line && running.has(line)) line.progress = d.text;
      break;
    }
    case "tool_result": {
      const line = r.lines.get(`${d.run}/${d.step}/${d.index}`);
      if (line) callDone(line, d);
      const li = r.calls.get(`${d.run}/${d.step}/${d.index}`);
      if (!li) break;
      li.dataset.ok = d.ok;
      li.querySelector(".ms").textContent = `${d.ok ? "✓" : "✗"} ${Math.round(d.ms)} ms`;
      if (!d.ok) li.querySelector(".decision").classList.add("failed");
      const details = li.querySelector("details");
      details.append(el("div", "muted", "result"), el("pre", "result", JSON.stringify(d.output, null, 1)));
      break;
    }
    case "answer":
      if (live && $("speak").checked) speak(d.text);
      r.answered = true;
      r.text.textContent = d.text;
      r.bubble.classList.remove("writing");
      r.bubble.classList.add("answered");
      break;
    case "error":
      traceItem("step failed").textContent = `run ${d.run}: ${d.message}`;
      break;
  }
}

function onDone(d) {
  const r = runs.get(d.run);
  setBusy(false);
  // A run may have taught a place, noted a fact, and it is logged.
  if (live) loadMemory();
  if (!r) return;
  r.bubble.classList.remove("writing");
  if (d.error) {
    r.bubble.classList.add("failed");
    r.text.textContent = `The agent failed: ${d.error}`;
    return;
  }
  const secs = (d.timings.total_ms / 1000).toFixed(1);
  const finish = d.finish === "answer" ? "" : ` · ${d.finish.replace("_", " ")}`;
  r.bubble.append(el("span", "meta", `${d.calls} call${d.calls === 1 ? "" : "s"} · ${secs} s${finish}`));
  scrollDown($("messages"));
}

async function submit() {
  const text = $("prompt").value.trim();
  if (!text) return;
  try {
    const r = await post("/api/ask", { text, language: $("language").value });
    $("prompt").value = "";
    if (r.stopped) notice("Stopped: the e-stop is engaged. Reset it to move again.");
  } catch (err) {
    notice(err.message);
  }
}

// Send stays enabled while the agent works: a stop typed or spoken then is taken at
// once (the server engages the e-stop); anything else is refused until the answer.
function setBusy(busy) {
  $("clear").disabled = busy;
  document.body.dataset.busy = busy;
}

// ---- approvals -------------------------------------------------------------------

function showApproval() {
  const dialog = $("approval");
  const next = approvals.keys().next();
  if (next.done) {
    shownApproval = null;
    if (dialog.open) dialog.close();
    return;
  }
  const id = next.value;
  const a = approvals.get(id);
  if (shownApproval !== id) settle();
  shownApproval = id;
  dialog.dataset.id = id;
  $("approval-name").textContent = a.name;
  $("approval-args").textContent = JSON.stringify(a.arguments, null, 2);
  $("approval-time").textContent = `Refused by itself after ${a.timeout_s} s without an answer, or at an e-stop.`;
  if (!dialog.open) dialog.showModal();
}

function settle() {
  for (const b of [$("approve"), $("deny")]) b.disabled = true;
  setTimeout(() => { for (const b of [$("approve"), $("deny")]) b.disabled = false; }, SETTLE_MS);
}

async function answerApproval(approve) {
  if (shownApproval === null || $("approve").disabled) return;
  // One answer per call shown: the buttons wait for the next call to settle.
  for (const b of [$("approve"), $("deny")]) b.disabled = true;
  try {
    await post("/api/approval", { id: shownApproval, approve });
  } catch (e) {
    notice(e.message);
    settle();
  }
}

// ---- e-stop ----------------------------------------------------------------------

function setEstop(s) {
  $("estop-banner").hidden = !s.engaged;
  $("estop-source").textContent = s.engaged && s.source ? `(by ${s.source})` : "";
  document.body.dataset.estop = s.engaged;
}

// ---- speech ---------------------------------------------------------------------

// The longest recording, as the recogniser takes it.
const MAX_RECORDING_S = 29;

async function startTalk() {
  const stream = await navigator.mediaDevices.getUserMedia({ audio: { channelCount: 1 } });
  const ctx = new AudioContext();
  const src = ctx.createMediaStreamSource(stream);
  const node = ctx.createScriptProcessor(4096, 1, 1);
  const chunks = [];
  node.onaudioprocess = (e) => chunks.push(new Float32Array(e.inputBuffer.getChannelData(0)));
  src.connect(node);
  node.connect(ctx.destination);
  const timer = setTimeout(() => stopTalk().catch((e) => notice(e.message)), MAX_RECORDING_S * 1000);
  rec = { ctx, stream, src, node, chunks, timer, started: performance.now() };
  $("talk").classList.add("recording");
  $("talk").textContent = "■ Send";
  notice("Listening… click again (or release) to send.");
}

async function stopTalk() {
  const r = rec;
  if (!r) return;
  rec = null;
  clearTimeout(r.timer);
  r.node.disconnect();
  r.src.disconnect();
  r.stream.getTracks().forEach((t) => t.stop());
  const rate = r.ctx.sampleRate;
  await r.ctx.close();
  $("talk").classList.remove("recording");
  $("talk").textContent = "… transcribing";
  $("talk").disabled = true;
  try {
    const resp = await fetch("/api/transcribe", {
      method: "POST",
      headers: { "Content-Type": "audio/wav" },
      body: wav(r.chunks, rate),
    });
    const data = await resp.json().catch(() => ({}));
    if (!resp.ok) throw new Error(data.error || `HTTP ${resp.status}`);
    if (!data.text) {
      notice("Nothing was heard; speak closer to the microphone.");
      return;
    }
    notice(`Heard in ${(data.ms / 1000).toFixed(1)} s.`);
    $("prompt").value = data.text;
    await submit();
  } finally {
    $("talk").textContent = "● Talk";
    $("talk").disabled = false;
  }
}

// 16-bit mono PCM WAV of the recorded chunks.
function wav(chunks, rate) {
  const n = chunks.reduce((a, c) => a + c.length, 0);
  const buf = new ArrayBuffer(44 + n * 2);
  const v = new DataView(buf);
  const text = (at, s) => { for (let i = 0; i < s.length; i++) v.setUint8(at + i, s.charCodeAt(i)); };
  text(0, "RIFF"); v.setUint32(4, 36 + n * 2, true); text(8, "WAVEfmt ");
  v.setUint32(16, 16, true); v.setUint16(20, 1, true); v.setUint16(22, 1, true);
  v.setUint32(24, rate, true); v.setUint32(28, rate * 2, true); v.setUint16(32, 2, true);
  v.setUint16(34, 16, true); text(36, "data"); v.setUint32(40, n * 2, true);
  let at = 44;
  for (const c of chunks) {
    for (const s of c) { v.setInt16(at, Math.max(-1, Math.min(1, s)) * 32767, true); at += 2; }
  }
  return new Blob([buf], { type: "audio/wav" });
}

async function speak(text) {
  const language = $("language").value === "auto" ? "en" : $("language").value;
  try {
    const r = await fetch("/api/say", {
      method: "POST",
      headers: { "Content-Type": "application/json" },
      body: JSON.stringify({ text, language }),
    });
    if (!r.ok) throw new Error((await r.json().catch(() => ({}))).error || `HTTP ${r.status}`);
    const audio = new Audio(URL.createObjectURL(await r.blob()));
    await audio.play();
  } catch (e) {
    notice(`Cannot speak the answer: ${e.message}`);
  }
}

// ---- robot view ------------------------------------------------------------------

function requestDraw() {
  if (drawing) return;
  drawing = true;
  requestAnimationFrame(() => { drawing = false; draw(); });
}

function draw() {
  const c = $("canvas");
  const g = c.getContext("2d");
  const W = c.width, H = c.height;
  g.clearRect(0, 0, W, H);
  if (!view) {
    g.fillStyle = "#667085";
    g.font = "14px system-ui";
    g.fillText("No pose topic (ferrosa serve --pose-topic TOPIC)", 12, H / 2);
    return;
  }
  let [x0, y0, x1, y1] = view.bounds || fit();
  const scale = Math.min(W / (x1 - x0), H / (y1 - y0));
  const px = (x) => (x - x0) * scale;
  const py = (y) => H - (y - y0) * scale;
  g.strokeStyle = "#cdd9ea";
  g.lineWidth = 1;
  for (let m = Math.ceil(x0); m <= x1; m++) { g.beginPath(); g.moveTo(px(m), 0); g.lineTo(px(m), H); g.stroke(); }
  for (let m = Math.ceil(y0); m <= y1; m++) { g.beginPath(); g.moveTo(0, py(m)); g.lineTo(W, py(m)); g.stroke(); }
  g.font = "12px system-ui";
  for (const pl of places) {
    g.fillStyle = pl.kept_in === "memory" ? "#b54708" : "#667085";
    g.beginPath();
    g.arc(px(pl.x), py(pl.y), 4, 0, 2 * Math.PI);
    g.fill();
    g.fillText(pl.name, px(pl.x) + 6, py(pl.y) - 4);
  }
  c.dataset.places = places.map((pl) => pl.name).join("|");
  if (trail.length > 1) {
    g.strokeStyle = "#2457c5";
    g.lineWidth = 2;
    g.beginPath();
    g.moveTo(px(trail[0].x), py(trail[0].y));
    for (const p of trail) g.lineTo(px(p.x), py(p.y));
    g.stroke();
  }
  const p = trail[trail.length - 1];
  if (!p) return;
  g.save();
  g.translate(px(p.x), py(p.y));
  g.rotate(-p.theta);
  g.fillStyle = document.body.dataset.estop === "true" ? "#c8102e" : "#137333";
  g.beginPath();
  g.moveTo(14, 0);
  g.lineTo(-9, 8);
  g.lineTo(-9, -8);
  g.closePath();
  g.fill();
  g.restore();
  c.dataset.x = p.x.toFixed(3);
  c.dataset.y = p.y.toFixed(3);
  c.dataset.theta = p.theta.toFixed(3);
  $("pose-text").textContent =
    `x ${p.x.toFixed(2)} m, y ${p.y.toFixed(2)} m, heading ${(p.theta * 180 / Math.PI).toFixed(0)}°`;
}

// The trail's extent with a margin, square, at least 2 m across.
function fit() {
  if (!trail.length) return [-1, -1, 1, 1];
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  for (const p of trail) { x0 = Math.min(x0, p.x); y0 = Math.min(y0, p.y); x1 = Math.max(x1, p.x); y1 = Math.max(y1, p.y); }
  const side = Math.max(2, x1 - x0, y1 - y0) * 1.2;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return [cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2];
}

// ---- start -----------------------------------------------------------------------

function connect() {
  const es = new EventSource("/api/events");
  es.onopen = () => { $("offline").hidden = true; };
  es.onerror = () => { $("offline").hidden = false; live = false; };
  es.addEventListener("ready", () => { live = true; });
  const on = (kind, f) => es.addEventListener(kind, (e) => f(JSON.parse(e.data)));
  on("request", onRequest);
  on("agent", onAgent);
  on("done", onDone);
  on("approval", (a) => { approvals.set(a.id, a); showApproval(); });
  on("approved", (a) => {
    approvals.delete(a.id);
    const li = traceItem(`step ${a.approved ? "confirmed" : "refused"}`);
    li.textContent = `approval ${a.id}: ${a.approved ? "approved" : "refused"} (${a.why})`;
    showApproval();
  });
  on("estop", (s) => { setEstop(s); requestDraw(); });
  on("pose", (p) => { trail.push(p); if (trail.length > 4000) trail.shift(); requestDraw(); });
  on("cleared", () => $("messages").append(el("li", "agent", "— conversation cleared —")));
  on("memory", () => loadMemory());
}

// ---- memory ----------------------------------------------------------------------

async function loadMemory() {
  const r = await fetch("/api/memory");
  const m = await r.json().catch(() => ({}));
  if (!r.ok) { notice(m.error || `HTTP ${r.status}`); return; }
  places = m.places || [];
  $("memory-robot").textContent = m.robot ? `(${m.robot})` : "";
  $("memory-why").hidden = m.kept !== false;
  $("memory-why").textContent = m.kept === false ? `Nothing is kept: ${m.why}` : "";
  const list = (id, items, line) => {
    const ul = $(id);
    ul.replaceChildren(...items.map(line));
    if (!items.length) ul.append(el("li", "muted", "none"));
  };
  list("memory-places", places, (pl) => {
    const li = el("li");
    li.append(el("span", "what", `${pl.name} · x ${pl.x.toFixed(2)}, y ${pl.y.toFixed(2)}`),
      el("span", "muted", pl.kept_in));
    if (pl.kept_in === "memory") li.append(forgetButton({ place: pl.name }));
    return li;
  });
  list("memory-facts", m.facts || [], (f) => {
    const li = el("li");
    li.append(el("span", "what", f.text), forgetButton({ fact: f.id }));
    return li;
  });
  list("memory-runs", m.runs || [], (run) => {
    const li = el("li");
    li.append(el("span", "what", run.request), el("span", "muted", run.at.slice(0, 16).replace("T", " ")));
    li.title = run.answer;
    return li;
  });
  requestDraw();
}

function forgetButton(what) {
  const b = el("button", "small", "forget");
  b.type = "button";
  b.addEventListener("click", () => forget(what));
  return b;
}

async function forget(what) {
  try {
    await post("/api/memory/forget", what);
  } catch (e) {
    notice(e.message);
  }
}

async function start() {
  const r = await fetch("/api/state");
  if (!r.ok) {
    notice((await r.json().catch(() => ({}))).error || `HTTP ${r.status}`);
    return;
  }
  const info = await r.json();
  $("engine").textContent = `robot: ${info.robot} · model: ${info.engine}`;
  const select = $("language");
  for (const l of info.languages) select.append(new Option(l.name, l.code));
  select.value = localStorage.getItem("ferrosa.language") || info.language || "auto";
  select.addEventListener("change", () => localStorage.setItem("ferrosa.language", select.value));
  if (!info.trace) $("download").hidden = true;
  view = info.view;
  trail = info.trail || [];
  setEstop(info.estop);
  setBusy(info.busy);
  draw();
  loadMemory();

  $("ask").addEventListener("submit", (e) => { e.preventDefault(); submit(); });
  // Click to start and click to send, or hold while speaking and release to send.
  $("talk").addEventListener("pointerdown", () => {
    if (rec) return;
    startTalk().catch((e) => notice(`Cannot record: ${e.message}`));
  });
  $("talk").addEventListener("pointerup", () => {
    if (rec && performance.now() - rec.started > 600) stopTalk().catch((e) => notice(e.message));
  });
  $("speak").checked = localStorage.getItem("ferrosa.speak") === "true";
  $("speak").addEventListener("change", () => localStorage.setItem("ferrosa.speak", $("speak").checked));
  $("estop").addEventListener("click", () => post("/api/estop").catch((e) => notice(e.message)));
  $("reset").addEventListener("click", () => post("/api/reset").catch((e) => notice(e.message)));
  $("clear").addEventListener("click", () => post("/api/clear").catch((e) => notice(e.message)));
  $("forget-all").addEventListener("click", () => {
    if (confirm("Delete every place taught, fact and logged request this robot keeps?")) forget({ all: true });
  });
  $("forget-runs").addEventListener("click", () => forget({ runs: true }));
  $("approve").addEventListener("click", () => answerApproval(true));
  $("deny").addEventListener("click", () => answerApproval(false));
  // Escape denies rather than leaving the agent waiting on a hidden question.
  $("approval").addEventListener("cancel", (e) => { e.preventDefault(); answerApproval(false); });
  connect();
}

start();
