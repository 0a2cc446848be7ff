// needle live: the page's side. The server sends a snapshot of the view
// when the page opens ("snapshot") and what changed ten times a second
// ("update"); a page that fell behind is told to start afresh ("lagged").
// Plots are uPlot (bundled, MIT: /assets/uPlot-LICENSE); the x-y line
// drawing (inOrder) and the chart width are charts.js's, shared with the
// reports.
"use strict";

// A point is [t_s, x_mm, force_n, model_n, residual_n, phase].
const T = 0, X = 1, F = 2, MODEL = 3, RESIDUAL = 4, PHASE = 5;
const INSERTIONS_KEPT = 5;
const POINTS_PER_INSERTION = 12000;
const EVENTS_KEPT = 200;
const NOTES_KEPT = 100;
const REPLIES_KEPT = 100;
const PHASE_FILL = [null, "rgba(255, 200, 0, 0.15)", "rgba(0, 140, 255, 0.12)", "rgba(150, 60, 255, 0.12)"];
const EVENT_COLOUR = { contact: "#2a7", puncture: "#d22", structure: "#e80", exit: "#27d", fault: "#000" };

let view = { device: {}, insertions: [], events: [], notes: [] };
let plots = null;
let drawing = false;

function byPositionSeries() {
  const series = [{}];
  for (let k = 0; k < INSERTIONS_KEPT; k++) {
    const newest = k === INSERTIONS_KEPT - 1;
    const alpha = newest ? 1 : 0.15 + 0.12 * k;
    series.push({
      label: newest ? "measured, this insertion" : `measured, ${INSERTIONS_KEPT - 1 - k} before`,
      stroke: `rgba(20, 60, 200, ${alpha})`, width: newest ? 2 : 1,
      paths: inOrder, points: { show: false }, facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }],
    });
  }
  series.push({
    label: "model, this insertion", stroke: "#d22", width: 1.5, dash: [6, 4],
    paths: inOrder, points: { show: false }, facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }],
  });
  return series;
}

function makePlots() {
  const byPosition = new uPlot({
    mode: 2, width: chartWidth(), height: 300,
    scales: { x: { time: false, auto: true }, y: { auto: true } },
    axes: [{ label: "position (mm)" }, { label: "force (N)" }],
    legend: { live: false },
    series: byPositionSeries(),
    hooks: { draw: [markEventsAtPosition] },
  }, [null, ...Array(INSERTIONS_KEPT + 1).fill([[], []])], document.getElementById("by-position"));

  const byTime = new uPlot({
    width: chartWidth(), height: 260,
    scales: { x: { time: false } },
    axes: [{ label: "time (s)" }, { label: "force (N)" }],
    series: [{ label: "time (s)" },
      { label: "measured", stroke: "rgb(20, 60, 200)", width: 1.5 },
      { label: "model", stroke: "#d22", width: 1.5, dash: [6, 4] }],
    hooks: { drawClear: [shadePhases], draw: [markEvents] },
  }, [[], [], []], document.getElementById("by-time"));

  const residual = new uPlot({
    width: chartWidth(), height: 160,
    scales: { x: { time: false } },
    axes: [{ label: "time (s)" }, { label: "residual (N)" }],
    series: [{ label: "time (s)" }, { label: "measured − model", stroke: "#555", width: 1 }],
    hooks: { drawClear: [shadePhases] },
  }, [[], []], document.getElementById("residual"));
  return { byPosition, byTime, residual };
}

function current() {
  return view.insertions[view.insertions.length - 1] || { number: 0, points: [] };
}

function shadePhases(u) {
  const pts = current().points;
  if (pts.length < 2) return;
  const ctx = u.ctx, top = u.bbox.top, height = u.bbox.height;
  let start = 0;
  for (let i = 1; i <= pts.length; i++) {
    if (i < pts.length && pts[i][PHASE] === pts[start][PHASE]) continue;
    const fill = PHASE_FILL[pts[start][PHASE]];
    if (fill) {
      const x0 = u.valToPos(pts[start][T], "x", true);
      const x1 = u.valToPos(pts[i - 1][T], "x", true);
      ctx.fillStyle = fill;
      ctx.fillRect(x0, top, Math.max(1, x1 - x0), height);
    }
    start = i;
  }
}

function markEvents(u) {
  const number = current().number, ctx = u.ctx;
  ctx.save();
  ctx.font = `${12 * devicePixelRatio}px sans-serif`;
  for (const e of view.events) {
    if (e.insertion !== number) continue;
    const x = u.valToPos(e.t_s, "x", true);

    ctx.strokeStyle = ctx.fillStyle = EVENT_COLOUR[e.kind] || "#000";
    ctx.beginPath();
    ctx.moveTo(x, u.bbox.top);
    ctx.lineTo(x, u.bbox.top + u.bbox.height);
    ctx.stroke();
    labelAt(u, x, u.bbox.top + 14 * devicePixelRatio, `${e.kind} ${e.force_n.toFixed(2)} N`);
  }
  ctx.restore();
}

// This insertion's events where they happened on the force–position
// curve: a dot and its kind.
function markEventsAtPosition(u) {
  const number = current().number, ctx = u.ctx;
  ctx.save();
  ctx.font = `${12 * devicePixelRatio}px sans-serif`;
  for (const e of view.events) {
    if (e.insertion !== number) continue;
    const x = u.valToPos(e.x_mm, "x", true), y = u.valToPos(e.force_n, "y", true);
    ctx.fillStyle = EVENT_COLOUR[e.kind] || "#000";
    ctx.beginPath();
    ctx.arc(x, y, 4 * devicePixelRatio, 0, 2 * Math.PI);
    ctx.fill();
    labelAt(u, x, y - 8 * devicePixelRatio, e.kind);
  }
  ctx.restore();
}

function column(points, i) {
  return points.map(p => p[i]);
}

function insertionName(number, newest) {
  if (number === 0) return "measured, before the first contact";
  return `measured, insertion ${number}${newest ? " (this one)" : ""}`;
}

function draw() {
  drawing = false;
  if (!plots) plots = makePlots();
  const kept = view.insertions.slice(-INSERTIONS_KEPT);
  const facets = [];
  for (let k = 0; k < INSERTIONS_KEPT; k++) {
    const ins = kept[k - (INSERTIONS_KEPT - kept.length)];
    facets.push(ins ? [column(ins.points, X), column(ins.points, F)] : [[], []]);
    // Each legend entry names its insertion; none for one not yet made.
    const entry = plots.byPosition.root.querySelectorAll(".u-legend .u-series")[k];
    if (entry) {
      entry.style.display = ins ? "" : "none";
      const label = entry.querySelector(".u-label");
      if (ins && label) label.textContent = insertionName(ins.number, k === INSERTIONS_KEPT - 1);
    }
  }
  const pts = current().points;
  facets.push([column(pts, X), column(pts, MODEL)]);
  plots.byPosition.setData([null, ...facets]);
  const t = column(pts, T);
  plots.byTime.setData([t, column(pts, F), column(pts, MODEL)]);
  plots.residual.setData([t, column(pts, RESIDUAL)]);
  drawDevice();
  drawEvents();
}

function later() {
  if (!drawing) {
    drawing = true;
    requestAnimationFrame(draw);
  }
}

function text(id, value) {
  document.getElementById(id).textContent = value;
}

function drawDevice() {
  const d = view.device;
  text("source", d.source || "–");
  text("tissue", d.tissue || "–");
  text("assist", d.assist == null ? "–" : `${d.assist}; target depth ${d.target_depth_mm.toFixed(1)} mm`);
  if (d.assist != null) mirrorControls(d);
  text("phase", d.phase || "–");
  text("zero", d.tare_counts == null ? "–" : `${d.tare_counts} counts`);
  text("faults", d.faults || "–");
  text("rate", d.samples_per_s == null ? "–" : `${d.samples_per_s} (device rate ${d.sample_rate_hz ?? "?"} Hz)`);
  text("dropped", d.frames_dropped ?? "–");
  text("recording", d.recording || "not recording");
  text("missing", `${d.samples_lost ?? 0} / ${d.samples_withheld ?? 0}`);
  const halt = document.getElementById("halt");
  halt.textContent = d.halt ? `HALT: ${d.halt_reason || "asserted"}` : "halt line released";
  halt.className = d.halt ? "bad" : "ok";
  if (d.connected === false) connection(false, d.problem ? `device not read: ${d.problem}` : "device gone");
}

function drawEvents() {
  const body = document.getElementById("events");
  body.replaceChildren(...view.events.slice().reverse().map(e => {
    const row = document.createElement("tr");
    row.className = e.kind;
    for (const v of [e.insertion, e.kind, e.t_s.toFixed(3), e.x_mm.toFixed(2), e.force_n.toFixed(3), e.confidence_percent.toFixed(1)]) {
      const cell = document.createElement("td");
      cell.textContent = v;
      row.appendChild(cell);
    }
    return row;
  }));
}

function connection(ok, what) {
  const c = document.getElementById("connection");
  c.textContent = what;
  c.className = ok ? "ok" : "bad";
}

function applyUpdate(u) {
  for (const [number, point] of u.points) {
    let ins = view.insertions[view.insertions.length - 1];
    if (!ins || ins.number !== number) {
      ins = { number, points: [] };
      view.insertions.push(ins);
      if (view.insertions.length > INSERTIONS_KEPT) view.insertions.shift();
    }
    ins.points.push(point);
    if (ins.points.length > POINTS_PER_INSERTION) ins.points.shift();
  }
  for (const e of u.events) {
    view.events.push(e);
    if (view.events.length > EVENTS_KEPT) view.events.shift();
  }
  for (const n of u.notes || []) {
    view.notes.push(n);
    if (view.notes.length > NOTES_KEPT) view.notes.shift();
    prependKept(document.getElementById("notes"), noteLine(n), NOTES_KEPT);
  }
  if (u.device) view.device = u.device;
  later();
}

// A log line first, the oldest dropped past `kept`: a tab left open for
// hours stays the size it was.
function prependKept(list, line, kept) {
  list.prepend(line);
  while (list.childElementCount > kept) list.lastElementChild.remove();
}

function noteLine(text) {
  const line = document.createElement("li");
  line.textContent = text;
  return line;
}

// The controls: each sends one request and logs the answer, the device's
// or the server's, in the page.
async function send(request) {
  let answer;
  try {
    const response = await fetch("/command", {
      method: "POST", headers: { "content-type": "application/json" }, body: JSON.stringify(request),
    });
    answer = await response.json();
  } catch (e) {
    answer = { ok: false, said: `${request.command}: the server did not answer (${e})` };
  }
  const line = document.createElement("li");
  line.className = answer.ok ? "done" : "refused";
  line.textContent = `${new Date().toLocaleTimeString()}  ${answer.said}`;
  prependKept(document.getElementById("replies"), line, REPLIES_KEPT);
}

function offerControls(library, modes) {
  const select = document.getElementById("tissue-name");
  if (select.options.length === 0) {
    for (const name of library) select.add(new Option(name, name));
  }
  const boxes = document.getElementById("assist-modes");
  if (boxes.childElementCount === 0) {
    for (const mode of modes) {
      const label = document.createElement("label");
      const box = document.createElement("input");
      box.type = "checkbox";
      box.value = mode;
      label.append(box, ` ${mode} `);
      boxes.appendChild(label);
    }
  }
}

// The controls show what the device runs whenever that changes (set
// from this page, another page, `needle device`, or a restart), and are
// the user's to edit in between.
const mirrored = {};
function mirror(key, value, apply) {
  if (value == null || mirrored[key] === value) return;
  mirrored[key] = value;
  apply();
}

function mirrorControls(d) {
  mirror("assist", `${d.assist};${d.target_depth_mm}`, () => {
    const on = new Set((d.assist || "").split(","));
    for (const box of document.querySelectorAll("#assist-modes input")) box.checked = on.has(box.value);
    if (d.target_depth_mm != null) document.getElementById("depth-mm").value = Number(d.target_depth_mm.toFixed(1));
  });
  mirror("tissue", d.tissue, () => {
    const select = document.getElementById("tissue-name");
    if ([...select.options].some(o => o.value === d.tissue)) select.value = d.tissue;
  });
}

function wireControls() {
  const click = (id, request) => document.getElementById(id).addEventListener("click", () => send(request()));
  click("tare", () => ({ command: "tare" }));
  click("rearm", () => ({ command: "rearm" }));
  click("stream-on", () => ({ command: "stream", on: true }));
  click("stream-off", () => ({ command: "stream", on: false }));
  click("record-on", () => ({ command: "record", on: true }));
  click("record-off", () => ({ command: "record", on: false }));
  click("select-tissue", () => ({ command: "tissue", name: document.getElementById("tissue-name").value }));
  click("set-assist", () => ({
    command: "assist",
    modes: [...document.querySelectorAll("#assist-modes input:checked")].map(b => b.value).join(",") || "none",
    depth_mm: Number(document.getElementById("depth-mm").value),
  }));
  document.getElementById("upload-tissue").addEventListener("click", async () => {
    const file = document.getElementById("tissue-file").files[0];
    if (!file) {
      send({ command: "upload", file_name: "(no file chosen)", toml: "", entry: null });
      return;
    }
    const entry = document.getElementById("tissue-entry").value.trim();
    send({ command: "upload", file_name: file.name, toml: await file.text(), entry: entry || null });
  });
}

function connect() {
  const source = new EventSource("/events");
  source.addEventListener("snapshot", e => {
    view = JSON.parse(e.data);
    document.getElementById("notes").replaceChildren(...view.notes.slice().reverse().map(noteLine));
    offerControls(view.library, view.assist_modes);
    connection(true, "live");
    later();
  });
  source.addEventListener("update", e => applyUpdate(JSON.parse(e.data)));
  source.addEventListener("lagged", () => {
    source.close();
    connect();
  });
  // The browser reconnects by itself; the server then sends a snapshot.
  source.onerror = () => connection(false, "server not reachable: retrying");
}

wireControls();
connect();
