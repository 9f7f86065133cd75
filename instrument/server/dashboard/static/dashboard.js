// The bench server's dashboard (docs/decisions/0085). Plain JavaScript, no build step.
//
// Everything it shows comes from the server's own API: GET /api/v1/... with the key the
// user signed in with, and the event stream (WebSocket /api/v1/events, the key offered as
// the subprotocol "bearer.KEY" because a browser cannot set headers on a WebSocket).
// Messages only change `S` (the state) and mark it dirty; the page is redrawn at most
// RENDER_HZ times a second, whatever the message rate. Everything kept grows to a bound:
// the plot keeps at most MAX_PLOT_POINTS points (every 2^k-th point of the run, k growing
// as the run does) and remembers the last SEEN_MAX point indices, the log MAX_LOG lines.
// A page that connects (or reconnects) mid-run reads the run's points so far page by page
// (GET /runs/current/points) while it follows the stream; a point in both is plotted once.
"use strict";

const API = "/api/v1";
const RENDER_HZ = 5;
const MAX_PLOT_POINTS = 4000;
const MAX_LOG = 300;
// The stream and the points so far overlap by what was published between the stream's
// start and the last page read (a few batches); remembering this many indices covers it.
const SEEN_MAX = 10000;
const MARKERS_UP_TO = 600;   // plans up to this many points get a marker per point (as the GUI)
const PALETTE = ["#1565c0", "#c62828", "#2e7d32", "#6a1b9a", "#ef6c00", "#00838f",
                 "#4e342e", "#ad1457"];
const OPERATOR_WORK = "pause, resume, abort, answer faults, press Stop all, change the queue " +
  "and set devices";
// What a client may set on each kind of device (instrument/server/device_settings.py).
const DEVICE_FIELDS = {
  lockin: ["sensitivity_v", "time_constant_s", "reference_source", "auto_range"],
  filter_wheel: ["position", "speed"],
  power_meter: ["wavelength_nm", "averaging", "auto_range", "zero"],
};

const $ = (id) => document.getElementById(id);

const S = {
  key: sessionStorage.getItem("scatterlab-key") || "",
  me: null,            // {name, role}
  status: null,        // the last GET /status (or hello's)
  run: null,           // {state, n_done, n_total, n_skipped, elapsed_s, eta_s, path, item_id, plan_kind}
  answers: [],         // what an operator may answer while paused
  pauseReason: "",
  fault: null,
  queue: {running: false, items: []},
  control: {holder: null, until: null},
  devices: null,
  settings: {},        // device-settings requests not yet ended, by role
  units: {},
  frame: null,
  log: [],
  connected: false,
  dirty: true,
};

// ---------------------------------------------------------------- HTTP
async function api(method, path, body) {
  const headers = {};
  if (S.key) headers["Authorization"] = "Bearer " + S.key;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  let resp;
  try {
    resp = await fetch(API + path, {method, headers,
                                    body: body === undefined ? undefined : JSON.stringify(body)});
  } catch (err) {
    return {ok: false, status: 0, data: {detail: "the server does not answer (" + err + ")"}};
  }
  let data = null;
  const type = resp.headers.get("content-type") || "";
  if (type.includes("json")) data = await resp.json();
  return {ok: resp.ok, status: resp.status, data, resp};
}

function refusal(r) {
  const d = r.data || {};
  let text = d.detail || ("HTTP " + r.status);
  if (Array.isArray(text)) text = JSON.stringify(text);
  if (d.reasons && d.reasons.length) text += ": " + d.reasons.join("; ");
  return text;
}

async function command(what, path, body) {
  const r = await api("POST", path, body === undefined ? {} : body);
  const text = r.ok ? (r.data && r.data.message) || "done" : "refused (" + r.status + "): " + refusal(r);
  $("command-result").textContent = what + ": " + text;
  $("command-result").className = r.ok ? "ok" : "error";
  addLog(r.ok ? "info" : "error", what + ": " + text);
  S.dirty = true;
  return r;
}

// ---------------------------------------------------------------- sign in
async function signIn(key) {
  S.key = key;
  const r = await api("GET", "/status");
  if (!r.ok) {
    $("signin").hidden = false;
    $("board").hidden = true;
    $("signin-error").textContent = r.status === 0 ? refusal(r)
      : (S.key ? "that key was refused: " : "this server needs a key: ") + refusal(r);
    S.key = "";
    sessionStorage.removeItem("scatterlab-key");
    return false;
  }
  if (S.key) sessionStorage.setItem("scatterlab-key", S.key);
  S.me = r.data.you;
  applyStatus(r.data);
  $("signin").hidden = true;
  $("board").hidden = false;
  $("signout").hidden = !S.key;
  $("who").textContent = "signed in as " + S.me.name + " (" + S.me.role + ")";
  $("who").dataset.role = S.me.role;
  loadAxes();
  loadRuns();
  connect();
  return true;
}

function signOut() {
  sessionStorage.removeItem("scatterlab-key");
  S.key = "";
  if (socket) { socket.onclose = null; socket.close(); }
  location.reload();
}

async function loadAxes() {
  const r = await api("GET", "/bench/axes");
  if (r.ok) {
    for (const [role, a] of Object.entries(r.data.axes)) S.units[role] = a.units || "";
    S.dirty = true;
  }
}

// ---------------------------------------------------------------- state from messages
function applyStatus(st) {
  S.status = st;
  $("bench-name").textContent = "bench " + st.bench;
  S.queue = {running: st.queue_running, items: st.queue || []};
  S.control = st.control || {holder: null, until: null};
  if (st.run) {
    const kind = S.run && S.run.item_id === st.run.item_id ? S.run.plan_kind : null;
    S.run = Object.assign({plan_kind: kind, eta_s: null}, st.run);
    S.answers = st.run.answers || [];
    S.pauseReason = st.run.pause_reason || "";
  } else if (S.run && ["running", "paused", "starting"].includes(S.run.state)) {
    S.run.state = "ended";
  }
  S.dirty = true;
}

function handle(msg) {
  const d = msg.data;
  switch (msg.type) {
    case "hello":
      S.me = {name: d.name, role: d.role};
      applyStatus(d.status);
      addLog("info", "connected to bench " + d.bench + " (protocol " + d.protocol + ")" +
             (d.status.run ? "; a run is in progress: reading its points so far" : ""));
      if (d.status.run) Backfill.start();
      break;
    case "run_started":
      S.run = {state: "running", n_done: d.n_done, n_total: d.n_total, n_skipped: 0,
               elapsed_s: 0, eta_s: d.estimated_s, path: d.path, item_id: d.item_id,
               plan_kind: d.plan_kind};
      S.fault = null; S.answers = []; S.pauseReason = "";
      Backfill.stop();   // its pages were the previous run's
      Plot.reset(d.plan_kind, d.n_total);
      addLog("info", "run started: " + baseName(d.path) + " (" + d.plan_kind + ", " +
             d.n_total + " points" + (d.n_done ? ", " + d.n_done + " already done" : "") + ")");
      loadRuns();
      break;
    case "backfill":   // a resumed run's points from before its resumption
      if (d.part === 1) addLog("info", "the run's " + d.n_points + " points stored before " +
                               "it was resumed");
      // falls through: drawn as points are
    case "points":
      if (Backfill.holds(d.items)) break;
      if (S.run && !S.run.plan_kind) Plot.guess(d.items);
      Plot.add(d.items);
      break;
    case "progress":
      if (!S.run) S.run = {state: "running", item_id: null, plan_kind: null};
      Object.assign(S.run, {n_done: d.n_done, n_total: d.n_total, elapsed_s: d.elapsed_s,
                            eta_s: d.eta_s});
      break;
    case "fault":
      S.fault = d;
      addLog("fault", "fault: " + d.device + ": " + d.cause + " → " + d.action +
             (d.index !== null ? " (point " + d.index + ")" : ""));
      break;
    case "paused":
      if (S.run) S.run.state = "paused";
      S.answers = d.answers || [];
      S.pauseReason = d.reason;
      addLog(S.answers.includes("skip") ? "fault" : "info", "paused: " + d.reason);
      break;
    case "resumed":
      if (S.run) S.run.state = "running";
      S.fault = null; S.answers = []; S.pauseReason = "";
      addLog("info", "resumed");
      break;
    case "run_finished":
      if (!S.run) S.run = {item_id: null, plan_kind: null};
      Object.assign(S.run, {state: d.status, n_done: d.n_done, n_total: d.n_total,
                            n_skipped: d.n_skipped, elapsed_s: d.elapsed_s, eta_s: 0,
                            path: d.path});
      S.answers = [];
      addLog(d.status === "finished" ? "info" : "fault",
             "run " + d.status + ": " + baseName(d.path) + (d.message ? " (" + d.message + ")" : ""));
      loadRuns();
      break;
    case "queue":
      if (S.queue.running !== d.running) addLog("info", "queue " + (d.running ? "started" : "stopped"));
      S.queue = {running: d.running, items: d.items};
      break;
    case "item_finished":
      addLog(d.outcome === "finished" || d.outcome === "stop marker" ? "info" : "fault",
             "queue item " + d.item_id + " (" + d.name + "): " + d.outcome);
      break;
    case "control":
      S.control = d;
      addLog("info", d.holder ? "control taken by " + d.holder : "control released");
      break;
    case "bench":
      addLog("info", d.message);
      loadAxes();
      break;
    case "manual":
      addLog(d.what === "stop all" ? "fault" : "info", d.who + ": " + d.what + ": " + d.message);
      break;
    case "devices":
      S.devices = d;
      break;
    case "device_settings":   // applying, then done, failed or cancelled
      if (d.state === "applying") S.settings[d.device] = d;
      else {
        if (S.settings[d.device] && S.settings[d.device].request_id === d.request_id) {
          delete S.settings[d.device];
        }
        addLog(d.state === "done" ? "info" : "error", d.who + ": " + d.message);
      }
      break;
    case "frame":
      S.frame = d;
      break;
    case "missed":
      addLog("info", "this page fell behind and skipped " + Object.entries(d.counts)
             .map(([k, n]) => n + " " + k).join(", ") + " display messages");
      break;
    default:
      break;  // a newer server's message type: nothing to show
  }
  S.dirty = true;
}

function addLog(cls, text) {
  S.log.push({t: new Date(), cls, text});
  if (S.log.length > MAX_LOG) S.log.splice(0, S.log.length - MAX_LOG);
  S.dirty = true;
}

// ---------------------------------------------------------------- event stream
let socket = null;
let retryMs = 500;

function connect() {
  const url = (location.protocol === "https:" ? "wss://" : "ws://") + location.host + API + "/events";
  const protocols = ["scatterlab.v1"];
  if (S.key) protocols.push("bearer." + S.key);
  socket = new WebSocket(url, protocols);
  socket.onopen = () => { retryMs = 500; };
  socket.onmessage = (ev) => {
    let msg;
    try { msg = JSON.parse(ev.data); } catch (err) { return; }
    if (msg.type === "hello") { S.connected = true; }
    handle(msg);
  };
  socket.onclose = () => {
    if (S.connected) addLog("fault", "lost the server: reconnecting");
    S.connected = false;
    S.dirty = true;
    // a restarted server is found again by trying, a little less often each time
    setTimeout(reconnect, retryMs);
    retryMs = Math.min(retryMs * 2, 4000);
  };
}

async function reconnect() {
  const r = await api("GET", "/status");
  if (r.status === 401) { signOut(); return; }
  if (r.ok) { applyStatus(r.data); loadRuns(); }
  connect();
}

// ---------------------------------------------------------------- the run's points so far
// After the stream's hello (so nothing published since is missed: the server stores a
// point before it sends it), the pages of GET /runs/current/points from ordinal 0 up to
// its total. Stream points that arrive before the first page (which names the plan, and so
// the picture) wait for it; later ones are plotted at once. Plot.add skips an index it has
// seen, whichever of the two brought it first.
const Backfill = {
  gen: 0, early: null,
  pageSize: 5000,   // the server's largest page (instrument/server/points.py)

  async start() {
    const gen = ++this.gen;
    this.early = [];
    Plot.clear();
    let since = 0, read = true;
    for (;;) {
      const r = await api("GET", "/runs/current/points?since=" + since + "&limit=" + this.pageSize);
      if (gen !== this.gen) return;   // a new run, or a newer connection, took over
      if (!r.ok) {
        addLog("fault", "could not read the run's points so far: " + refusal(r) +
               "; the plot shows the run's points from now on");
        read = false;
        break;
      }
      const page = r.data;
      if (since === 0) this.first(page.run);
      Plot.add(page.items);
      since = page.next;
      if (since >= page.total || page.items.length === 0) break;
    }
    this.flush();
    if (read) addLog("info", "plotted the run's points so far (" + since + ")");
  },

  first(run) {   // the first page: the plan's picture, then what the stream brought meanwhile
    const kind = run ? run.plan_kind : null;
    if (S.run && kind && !S.run.plan_kind) S.run.plan_kind = kind;
    Plot.reset(kind || "series", run ? run.n_total : (S.run ? S.run.n_total : 0));
    this.flush();
  },

  flush() {
    const early = this.early;
    this.early = null;
    if (early && early.length) Plot.add(early);
  },

  holds(items) {   // before the first page: keep the stream's points for it
    if (this.early === null) return false;
    for (const p of items) this.early.push(p);
    return true;
  },

  stop() { this.gen += 1; this.early = null; },
};

// ---------------------------------------------------------------- the live plot (Bokeh)
// The same pictures as the GUI's live plot (gui/qt/live_plot.py) for the plans a server
// runs: in-plane BRDF and the calibrations that share its picture: signal against signed
// θr, one curve per θi, log signal axis; hemisphere scans: a polar map of the scattered
// directions (radius θr, angle φr) coloured by log signal; every other plan: signal per
// point (a light-field or sphere capture's latest frame is in the camera panel).
const Plot = {
  kind: null, nTotal: 0, stride: 1, kept: [], quantity: null, fig: null, viewPromise: null,
  needsBuild: false,
  sources: new Map(), drawnVersion: -1, version: 0, seen: new Set(), ring: [], ringAt: 0,

  pictureOf(planKind) {
    if (planKind === "brdf_hemisphere") return "hemisphere";
    return ["brdf_in_plane", "reference", "signature"].includes(planKind) ? "in_plane" : "series";
  },

  reset(planKind, nTotal) {
    this.clear();
    this.kind = this.pictureOf(planKind);
    this.nTotal = nTotal || 0;
    this.build();
  },

  clear() {   // no picture until the next reset (or the first points)
    this.kind = null;
    this.stride = 1;
    this.kept = [];
    this.seen = new Set();   // the last SEEN_MAX indices, ring[] in arrival order
    this.ring = new Array(SEEN_MAX);
    this.ringAt = 0;
    this.quantity = null;
    this.version += 1;
  },

  isNew(index) {   // each index once; the oldest remembered is forgotten by its key
    // (not by iterating the Set from its start: V8 steps over the deleted entries there,
    // which made a points message 30 times dearer)
    if (this.seen.has(index)) return false;
    const old = this.ring[this.ringAt];
    if (old !== undefined) this.seen.delete(old);
    this.ring[this.ringAt] = index;
    this.ringAt = (this.ringAt + 1) % SEEN_MAX;
    this.seen.add(index);
    return true;
  },

  guess(items) {  // joined mid-run, before any run_started: points with angles are in-plane
    if (this.kind !== null) return;
    const withAngles = items.some((p) => p.angles && p.angles[2] !== null);
    this.reset(withAngles ? "brdf_in_plane" : "series", S.run ? S.run.n_total : 0);
  },

  add(items) {
    if (this.kind === null) this.reset("series", S.run ? S.run.n_total : 0);
    for (const p of items) {
      if (!this.isNew(p.index) || p.status !== "ok") continue;
      if (this.quantity === null) {
        if (p.signal !== null) this.quantity = "signal";
        else if (p.power_w !== null) this.quantity = "power";
        else continue;
        this.build();
      }
      const y = this.quantity === "signal" ? p.signal : p.power_w;
      if (y === null || p.index % this.stride !== 0) continue;
      let x = p.index, group = 0;
      if (this.kind === "in_plane") {
        if (!p.angles || p.angles[2] === null) continue;
        const [ti, phii, tr, phir] = p.angles;
        const d = ((phir - phii) % 360 + 360) % 360;
        x = Math.abs(d - 180) < 90 ? tr : -tr;                     // > 0: specular side
        group = Math.round((Math.abs(((phii % 360) + 360) % 360 - 180) < 90 ? -ti : ti) * 10) / 10;
        if (!(y > 0)) continue;                                    // a log axis
      } else if (this.kind === "hemisphere") {
        if (!p.angles || p.angles[2] === null || !(y > 0)) continue;
        const [tr, phir] = [p.angles[2], p.angles[3] * Math.PI / 180];
        this.kept.push({i: p.index, x: tr * Math.cos(phir), y: tr * Math.sin(phir),
                        v: Math.log10(y), g: 0});
        continue;
      }
      this.kept.push({i: p.index, x, y, g: group});
    }
    while (this.kept.length > MAX_PLOT_POINTS) {   // decimate: every other point kept so far
      this.stride *= 2;
      this.kept = this.kept.filter((k) => k.i % this.stride === 0);
    }
    this.version += 1;
  },

  build() {   // (re)made on the next draw, once: a new run, or the first value's quantity
    this.needsBuild = true;
    this.drawnVersion = -1;
  },

  make() {
    this.needsBuild = false;
    if (this.viewPromise) this.viewPromise.then((view) => view.remove());
    this.sources = new Map();
    $("plot").innerHTML = "";
    const yLabel = this.quantity === "power" ? "power (W)" : "signal (DN/µs)";
    const inPlane = this.kind === "in_plane";
    if (this.kind === "hemisphere") return this.makePolar(yLabel);
    this.fig = Bokeh.Plotting.figure({
      height: 300, sizing_mode: "stretch_width",
      x_axis_label: inPlane ? "θr (signed: > 0 specular side) (deg)" : "point",
      y_axis_label: yLabel, y_axis_type: inPlane ? "log" : "linear",
      tools: "pan,wheel_zoom,box_zoom,reset,save", toolbar_location: "right",
    });
    this.viewPromise = Bokeh.Plotting.show(this.fig, $("plot"));
  },

  makePolar(quantity) {   // rings at θr = 30°, 60°, 90°; colour: log10 of the quantity
    this.fig = Bokeh.Plotting.figure({
      height: 360, sizing_mode: "stretch_width", match_aspect: true,
      x_axis_label: "θr cos φr (deg)", y_axis_label: "θr sin φr (deg)",
      tools: "pan,wheel_zoom,box_zoom,reset,save", toolbar_location: "right",
    });
    for (const r of [30, 60, 90]) {
      const a = Array.from({length: 181}, (_, k) => k * 2 * Math.PI / 180);
      this.fig.line(a.map((t) => r * Math.cos(t)), a.map((t) => r * Math.sin(t)),
                    {line_color: "#9e9e9e"});
    }
    this.mapper = new Bokeh.LinearColorMapper({palette: Bokeh.Palettes.Viridis256});
    const src = new Bokeh.ColumnDataSource({data: {x: [], y: [], v: []}});
    this.fig.scatter({field: "x"}, {field: "y"}, {source: src, size: 9, line_color: null,
                     fill_color: {field: "v", transform: this.mapper}});
    this.fig.add_layout(new Bokeh.ColorBar({color_mapper: this.mapper,
                                            title: "log10 " + quantity}), "right");
    this.sources.set(0, src);
    this.viewPromise = Bokeh.Plotting.show(this.fig, $("plot"));
  },

  drawPolar() {
    const k = this.kept;
    const v = k.map((p) => p.v);
    if (v.length) { this.mapper.low = Math.min(...v); this.mapper.high = Math.max(...v); }
    this.sources.get(0).data = {x: k.map((p) => p.x), y: k.map((p) => p.y), v};
  },

  draw() {
    if (this.kind === null || this.drawnVersion === this.version) return;
    if (this.needsBuild) this.make();
    if (this.kind === "hemisphere") { this.drawPolar(); this.caption(); return; }
    this.drawnVersion = this.version;
    const groups = new Map();
    for (const k of this.kept) {
      if (!groups.has(k.g)) groups.set(k.g, {x: [], y: []});
      const g = groups.get(k.g);
      g.x.push(k.x); g.y.push(k.y);
    }
    const markers = this.nTotal > 0 && this.nTotal <= MARKERS_UP_TO;
    for (const [g, xy] of [...groups.entries()].sort((a, b) => a[0] - b[0])) {
      if (this.kind === "in_plane") {   // a curve along θr
        const order = xy.x.map((_, i) => i).sort((a, b) => xy.x[a] - xy.x[b]);
        xy.x = order.map((i) => xy.x[i]); xy.y = order.map((i) => xy.y[i]);
      }
      let src = this.sources.get(g);
      if (!src) {
        src = new Bokeh.ColumnDataSource({data: {x: [], y: []}});
        const colour = PALETTE[this.sources.size % PALETTE.length];
        const label = this.kind === "in_plane" ? "θi = " + g + "°" : undefined;
        const style = {source: src, line_color: colour, line_width: 2};
        if (label) style.legend_label = label;
        if (this.kind === "in_plane") this.fig.line({field: "x"}, {field: "y"}, style);
        if (markers || this.kind !== "in_plane") {
          this.fig.scatter({field: "x"}, {field: "y"},
                           {source: src, fill_color: colour, line_color: colour, size: 6});
        }
        this.sources.set(g, src);
      }
      src.data = {x: xy.x, y: xy.y};
    }
    this.caption();
  },

  caption() {
    const n = S.run ? S.run.n_done : 0;
    $("plot-caption").textContent = (S.run && S.run.plan_kind ? S.run.plan_kind + ": " : "") +
      n + " of " + (S.run ? S.run.n_total : "?") + " points, " + this.kept.length + " plotted" +
      (this.stride > 1 ? " (every " + this.stride + "th point: the plot keeps at most " +
                         MAX_PLOT_POINTS + ")" : "");
    $("plot").dataset.plotted = String(this.kept.length);
  },
};

// ---------------------------------------------------------------- drawing
function duration(s) {
  if (s === null || s === undefined || !isFinite(s)) return "—";
  s = Math.max(0, s);
  if (s < 10) return s.toFixed(1) + " s";
  if (s < 60) return Math.round(s) + " s";
  if (s < 3600) { const m = Math.floor(Math.round(s) / 60); return m + " min " + String(Math.round(s) % 60).padStart(2, "0") + " s"; }
  const mins = Math.round(s / 60);
  return Math.floor(mins / 60) + " h " + String(mins % 60).padStart(2, "0") + " min";
}

function baseName(p) { return p ? String(p).split("/").pop() : ""; }

function cell(tr, text, cls) {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  tr.appendChild(td);
  return td;
}

function isOperator() { return S.me && (S.me.role === "operator" || S.me.role === "admin"); }

function controlBlocker() {
  const c = S.control;
  if (c && c.holder && S.me && c.holder !== S.me.name && c.until * 1000 > Date.now()) {
    return "control is held by " + c.holder + " until " +
      new Date(c.until * 1000).toLocaleTimeString() + ": ask them to release it";
  }
  return "";
}

function setButton(id, enabled, why) {
  const b = $(id);
  b.disabled = !enabled;
  b.title = enabled ? "" : why;
}

function renderButtons() {
  const run = S.run;
  const state = run ? run.state : "none";
  const alive = state === "running" || state === "paused";
  const head = S.queue.items[0];
  const op = isOperator();
  const blocked = controlBlocker();
  const roleWhy = "your key is an " + (S.me ? S.me.role : "observer") +
    " key: only operators may " + OPERATOR_WORK;
  const gate = (id, possible, whyNot, needsControl = true) => {
    if (!op) return setButton(id, false, roleWhy);
    if (needsControl && blocked) return setButton(id, false, blocked);
    setButton(id, possible, whyNot);
  };
  gate("pause", state === "running", "no run is going on");
  gate("resume", (state === "paused" && S.answers.includes("resume")) ||
       (!alive && head && head.resumable), "nothing to resume");
  gate("abort", alive, "no run is going on");
  gate("stop-all", !!(S.status && S.status.connected), "no bench is connected", false);
  const idle = !!(S.devices && S.devices.owner === "idle") && !S.queue.running;
  gate("device-apply", idle && !S.settings[$("device-role").value],
       S.settings[$("device-role").value] ? "a change of this device is being applied"
       : "devices are set between runs, with the queue stopped");
  gate("queue-add", true, "");
  gate("plan-file", true, "");
  gate("queue-start", !S.queue.running, "the queue is running");
  gate("queue-stop", S.queue.running, "the queue is stopped");
  for (const a of ["retry", "skip", "abort"]) {
    gate("answer-" + a, S.answers.includes(a), "the run does not wait for this answer");
  }
  $("role-reason").textContent = !op ? "Buttons are greyed: " + roleWhy + "." :
    (blocked ? "Buttons are greyed: " + blocked + " (Stop all always works)." : "");
}

function renderRun() {
  const r = S.run;
  if (!r) {
    $("run-title").textContent = "no run";
    $("run-progress").value = 0;
    $("run-numbers").textContent = "";
  } else {
    const item = S.queue.items.find((i) => i.id === r.item_id);
    $("run-title").textContent = (item ? item.name + " — " : "") + baseName(r.path) + ": " + r.state;
    $("run-title").dataset.state = r.state;
    const total = r.n_total || 0, done = r.n_done || 0;
    $("run-progress").max = Math.max(total, 1);
    $("run-progress").value = done;
    $("run-numbers").textContent = done + " of " + total + " points" +
      (r.n_skipped ? " (" + r.n_skipped + " skipped)" : "") +
      " · elapsed " + duration(r.elapsed_s) +
      (r.state === "running" ? " · ETA " + duration(r.eta_s) : "");
    $("run-numbers").dataset.done = String(done);
  }
  const waiting = S.answers.includes("skip");
  $("fault-box").hidden = !waiting;
  if (waiting) {
    const f = S.fault;
    $("fault-text").textContent = "The run waits for an answer: " + S.pauseReason +
      (f ? " (" + f.device + ": " + f.cause + ")" : "");
  }
}

function renderQueue() {
  $("queue-state").textContent = S.queue.running ? "(running)" : "(stopped)";
  const body = $("queue").tBodies[0];
  body.innerHTML = "";
  for (const it of S.queue.items) {
    const tr = body.insertRow();
    cell(tr, String(it.id));
    cell(tr, it.name);
    cell(tr, it.state + (it.resumable ? " (resumable)" : ""));
    cell(tr, it.added_by);
  }
  if (!S.queue.items.length) cell(body.insertRow(), "empty").colSpan = 4;
}

function renderDevices() {
  const body = $("devices").tBodies[0];
  body.innerHTML = "";
  const d = S.devices;
  if (!d) { cell(body.insertRow(), "no reading yet").colSpan = 3; return; }
  for (const [role, a] of Object.entries(d.axes)) {
    const tr = body.insertRow();
    const units = S.units[role] || "";
    cell(tr, role);
    cell(tr, a.position === null ? "—" : a.position.toFixed(units === "mm" ? 4 : 3) + " " + units, "num");
    cell(tr, (a.moving ? "moving" : "still") + (a.homed ? "" : ", not homed"));
  }
  cameraRow(body, d);
  for (const [role, s] of Object.entries(d.states || {})) deviceRow(body, role, s);
  deviceChoices(d.states || {});
  $("light").textContent = "light: " + (d.light === null ? (d.owner === "run" ? "run controls it" : "—")
                                        : d.light ? "on" : "off") +
    " · bench " + (d.owner === "run" ? "owned by the run" : "idle");
}

// The lock-in's, filter wheel's and power meter's states (read between runs; during a run
// the state read before it), and a change of their settings in progress.
function deviceRow(body, role, s) {
  const v = s.values || {};
  const tr = body.insertRow();
  tr.id = "device-" + role;
  cell(tr, role);
  let reading = "—", state = "";
  if (s.kind === "lockin") {
    reading = v.r_v === null || v.r_v === undefined ? "R —" : "R " + num(v.r_v) + " V";
    state = "range " + num(v.sensitivity_v) + " V, τ " + num(v.time_constant_s) + " s, " + v.reference;
  } else if (s.kind === "filter_wheel") {
    reading = "slot " + v.position;
    state = "speed " + v.speed;
  } else if (s.kind === "power_meter") {
    reading = v.power_w === null || v.power_w === undefined ? "—" : num(v.power_w) + " W";
    state = "at " + num(v.wavelength_nm) + " nm";
  }
  if (s.error) state += " · " + s.error;
  const pending = S.settings[role];
  if (pending) state += " · applying… (request " + pending.request_id + ", " + pending.who + ")";
  cell(tr, reading, "num");
  cell(tr, state);
}

function deviceChoices(states) {   // the form's devices and their fields, kept as chosen
  const roles = Object.keys(states).filter((r) => DEVICE_FIELDS[states[r].kind]);
  const sel = $("device-role");
  if (sel.dataset.roles !== roles.join(",")) {
    const keep = sel.value;
    sel.innerHTML = "";
    for (const r of roles) sel.add(new Option(r, r));
    if (roles.includes(keep)) sel.value = keep;
    sel.dataset.roles = roles.join(",");
  }
  const kind = states[sel.value] ? states[sel.value].kind : "";
  const fields = DEVICE_FIELDS[kind] || [];
  const box = $("device-field");
  if (box.dataset.kind !== kind) {
    box.innerHTML = "";
    for (const f of fields) box.add(new Option(f, f));
    box.dataset.kind = kind;
  }
}

function settingValue(text) {   // as JSON carries it: true/false, a number, else the text
  const t = text.trim();
  if (t === "true" || t === "false") return t === "true";
  if (t !== "" && !isNaN(Number(t))) return Number(t);
  return t;
}

async function setDevice() {
  const role = $("device-role").value, field = $("device-field").value;
  if (!role || !field) return;
  const value = settingValue($("device-value").value);
  // "applying…" comes with the server's applying event (published before this answer;
  // its end may even arrive first on a fast device), never from the answer itself
  await command("set " + role + " " + field, "/bench/devices/" + encodeURIComponent(role) +
                "/settings", {changes: {[field]: value}});
}

// The camera's settings come with the idle bench's devices messages; during a run the
// run sets them, and the latest frame says the exposure it was taken with.
function cameraRow(body, d) {
  let reading = null, state = "";
  if (d.owner === "run") {
    if (!S.frame || S.frame.exposure_us === null || S.frame.exposure_us === undefined) return;
    reading = "exposure " + num(S.frame.exposure_us) + " µs";
    state = "run controls it (latest frame)";
  } else {
    if (!d.camera) return;   // no camera on this bench (or it did not answer)
    reading = d.camera.exposure_us === null ? "exposure —" : "exposure " + num(d.camera.exposure_us) + " µs";
    state = d.camera.gain === null ? "gain —" : "gain " + num(d.camera.gain);
  }
  const tr = body.insertRow();
  tr.id = "camera-row";
  cell(tr, "camera");
  cell(tr, reading, "num");
  cell(tr, state);
}

function num(v) { return Number(v.toPrecision(6)).toString(); }

function renderFrame() {
  const f = S.frame;
  if (!f || f.drawn) return;
  f.drawn = true;
  const [h, w] = f.shape;
  const canvas = $("frame");
  canvas.hidden = false;
  canvas.width = w; canvas.height = h;
  const ctx = canvas.getContext("2d");
  const img = ctx.createImageData(w, h);
  const raw = atob(f.data);
  for (let i = 0; i < w * h; i++) {
    const v = raw.charCodeAt(i);
    img.data[4 * i] = v; img.data[4 * i + 1] = v; img.data[4 * i + 2] = v; img.data[4 * i + 3] = 255;
  }
  ctx.putImageData(img, 0, 0);
  const exp = f.exposure_us === null || f.exposure_us === undefined ? "—"
    : f.exposure_us >= 1000 ? (f.exposure_us / 1000).toFixed(2) + " ms" : f.exposure_us.toFixed(0) + " µs";
  const sat = f.saturated === null || f.saturated === undefined ? "—" : (100 * f.saturated).toFixed(2) + " %";
  $("frame-caption").textContent = "point " + f.index + " · exposure " + exp +
    " · saturated " + sat + " · shown " + w + "×" + h + " (1 step = " + f.scale.toPrecision(3) + " DN)";
  $("frame-caption").className = f.saturated > 0 ? "warn" : "";
}

function renderLog() {
  const ol = $("log");
  ol.innerHTML = "";
  for (let i = S.log.length - 1; i >= 0; i--) {
    const e = S.log[i];
    const li = document.createElement("li");
    li.className = e.cls;
    li.textContent = e.t.toLocaleTimeString() + "  " + e.text;
    ol.appendChild(li);
  }
}

function render() {
  const badge = $("conn");
  badge.textContent = S.connected ? "live" : (S.me ? "reconnecting…" : "not connected");
  badge.className = "badge " + (S.connected ? "on" : "off");
  Plot.draw();
  renderFrame();
  if (!S.dirty) return;
  S.dirty = false;
  const c = S.control;
  $("control").textContent = c && c.holder ? "control: " + c.holder : "control: free";
  renderRun();
  renderButtons();
  renderQueue();
  renderDevices();
  renderLog();
}

// ---------------------------------------------------------------- run browser
function relativePath(p) {
  const root = S.status ? S.status.runs_dir : "";
  return root && p.startsWith(root + "/") ? p.slice(root.length + 1) : null;
}

function fileUrl(rel) { return API + "/runs/files/" + rel.split("/").map(encodeURIComponent).join("/"); }

async function getFile(rel) {
  const headers = S.key ? {Authorization: "Bearer " + S.key} : {};
  return fetch(fileUrl(rel), {headers});
}

async function loadRuns() {
  const r = await api("GET", "/runs?limit=50");
  if (!r.ok) return;
  const body = $("runs").tBodies[0];
  body.innerHTML = "";
  for (const run of r.data) {
    const tr = body.insertRow();
    tr.dataset.runId = run.run_id;
    cell(tr, baseName(run.path));
    cell(tr, run.plan_name + " (" + run.plan_kind + ")");
    cell(tr, run.sample);
    cell(tr, run.status);
    cell(tr, run.n_points + " / " + run.n_planned, "num");
    cell(tr, new Date(run.started * 1000).toLocaleString());
    const td = cell(tr, "");
    const rel = relativePath(run.path);
    if (rel) {
      const dl = document.createElement("button");
      dl.textContent = "Download";
      dl.className = "download";
      dl.onclick = () => download(rel);
      td.appendChild(dl);
      const rep = document.createElement("button");
      rep.textContent = "Report";
      rep.className = "open-report";
      rep.onclick = () => openReport(rel);
      td.appendChild(rep);
    }
  }
  if (!r.data.length) cell(body.insertRow(), "no runs yet").colSpan = 7;
}

async function download(rel) {
  const resp = await getFile(rel);
  if (!resp.ok) { addLog("error", "download " + rel + ": HTTP " + resp.status); return; }
  const url = URL.createObjectURL(await resp.blob());
  const a = document.createElement("a");
  a.href = url; a.download = baseName(rel);
  document.body.appendChild(a); a.click(); a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 60000);
}

function dataUrl(blob) {
  return new Promise((ok, fail) => {
    const rd = new FileReader();
    rd.onload = () => ok(rd.result);
    rd.onerror = () => fail(rd.error);
    rd.readAsDataURL(blob);
  });
}

// The analyses write their report beside the run: DIR/RUN/<pipeline>/index.html (ADR 0013).
async function openReport(rel) {
  const stem = rel.replace(/\.h5$/, "");
  for (const pipeline of ["fit", "lightfield", "spheres"]) {
    const folder = stem + "/" + pipeline;
    const resp = await getFile(folder + "/index.html");
    if (!resp.ok) continue;
    const doc = new DOMParser().parseFromString(await resp.text(), "text/html");
    // its figures are files beside it, read with the key like everything else, and put
    // into the page as data: URLs (the report is shown sandboxed: no scripts, no requests)
    for (const img of doc.querySelectorAll("img[src]")) {
      const src = img.getAttribute("src");
      if (/^[a-z]+:/i.test(src) || src.startsWith("/")) continue;
      const r = await getFile(folder + "/" + src);
      if (r.ok) img.setAttribute("src", await dataUrl(await r.blob()));
    }
    const frame = $("report");
    frame.srcdoc = "<!doctype html>" + doc.documentElement.outerHTML;
    frame.hidden = false;
    $("report-bar").hidden = false;
    $("report-title").textContent = pipeline + " report of " + baseName(rel);
    frame.dataset.loaded = rel;
    return;
  }
  addLog("info", "no analysis report for " + baseName(rel) + " yet (scatterlab fit " +
         baseName(rel) + " writes one)");
}

// ---------------------------------------------------------------- wiring
function wire() {
  $("signin-form").onsubmit = (e) => { e.preventDefault(); signIn($("key").value.trim()); };
  $("signout").onclick = signOut;
  $("pause").onclick = () => command("pause", "/run/pause", {now: false});
  $("resume").onclick = () => command("resume", "/run/resume", {answer: "resume"});
  $("abort").onclick = () => {
    if (confirm("Abort the run? It stays at the head of the queue, resumable.")) command("abort", "/run/abort");
  };
  $("stop-all").onclick = () => command("stop all", "/bench/stop-all");
  $("device-apply").onclick = setDevice;
  $("device-role").onchange = () => { deviceChoices(S.devices ? S.devices.states || {} : {});
                                      S.dirty = true; };
  $("answer-retry").onclick = () => command("retry", "/run/resume", {answer: "retry"});
  $("answer-skip").onclick = () => command("skip", "/run/resume", {answer: "skip"});
  $("answer-abort").onclick = () => command("abort", "/run/abort");
  $("queue-start").onclick = () => command("start queue", "/queue/start");
  $("queue-stop").onclick = () => command("stop queue", "/queue/stop");
  $("queue-add").onclick = async () => {
    const f = $("plan-file").files[0];
    if (!f) { $("command-result").textContent = "choose a plan file (.toml) first"; return; }
    if (f.size > 1 << 20) { $("command-result").textContent = f.name + " is too large for a plan"; return; }
    await command("add " + f.name, "/queue", {plan: await f.text()});
  };
  $("runs-refresh").onclick = loadRuns;
  $("report-close").onclick = () => {
    $("report").hidden = true; $("report-bar").hidden = true; $("report").srcdoc = "";
  };
  setInterval(render, 1000 / RENDER_HZ);
}

wire();
signIn(S.key).then((ok) => { if (!ok && !S.key) $("signin-error").textContent = ""; });
