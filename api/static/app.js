// uavbar-supervisor operator dashboard: telemetry over /api/telemetry, commands over REST.
// No build step. The token comes from the page address (#token=…, a fragment the browser
// never sends) or is asked for when a command needs it, and is kept for this browser tab only.
// ABORT never waits for it: the API takes an abort from this page's own origin without a
// valid token (docs/architecture.md, "The API's gate"), so it is sent at once, whatever the
// token and whatever dialog is open.
"use strict";

const STALE_AFTER_MS = 500;
const PLOT_SECONDS = 20;
const TOKEN_KEY = "uavbar-token";
const WS_TOKEN_REQUIRED = 4401;
const state = {
  telemetry: null, lastMessageAt: 0, socket: null, retryMs: 500,
  everConnected: false, everLive: false, stale: true, tokenRefused: false,
};
const plots = { error: [], solve: [] };

// ---- token ---------------------------------------------------------------------------------
function takeTokenFromAddress() {
  const match = location.hash.match(/token=([^&]+)/);
  if (match) {
    sessionStorage.setItem(TOKEN_KEY, decodeURIComponent(match[1]));
    window.history.replaceState(null, "", location.pathname + location.search);
  }
}

const storedToken = () => sessionStorage.getItem(TOKEN_KEY);

// The dialog is not modal: ABORT stays pressable while it is open, and Escape (abort)
// closes it. Closing it without a token keeps the stored one.
function askToken(note) {
  const dialog = document.getElementById("token-dialog");
  if (dialog.open) return new Promise((resolve) => dialog.addEventListener("close", () => resolve(storedToken()), { once: true }));
  return new Promise((resolve) => {
    const input = document.getElementById("token-input");
    document.getElementById("token-note").textContent = note || "";
    input.value = "";
    dialog.addEventListener("close", () => {
      const token = dialog.returnValue === "ok" ? input.value.trim() : "";
      if (token) {
        sessionStorage.setItem(TOKEN_KEY, token);
        state.tokenRefused = false;
      }
      resolve(token || null);
    }, { once: true });
    dialog.returnValue = "";
    dialog.show();
    input.focus();
  });
}

function closeTokenDialog() {
  const dialog = document.getElementById("token-dialog");
  if (dialog.open) dialog.close("");
}

async function token() {
  const stored = storedToken();
  if (stored && !state.tokenRefused) return stored;
  const note = stored ? "the stored token was refused (401): enter the right one" : "";
  return (await askToken(note)) || null;
}

function authorization(bearer) {
  return bearer ? { "Authorization": `Bearer ${bearer}` } : {};
}

// ---- commands ------------------------------------------------------------------------------
function show(reasonId, text, ok = false) {
  const element = document.getElementById(reasonId);
  element.textContent = text;
  element.classList.toggle("ok", ok);
}

function describe(detail) {
  if (Array.isArray(detail)) {
    return detail.map((d) => `${(d.loc || []).slice(1).join(".") || "body"}: ${d.msg}`).join("; ");
  }
  return String(detail ?? "");
}

async function send(method, path, body, reasonId, bearer) {
  let response;
  try {
    response = await fetch(path, {
      method,
      headers: { ...authorization(bearer), "Content-Type": "application/json" },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
  } catch (error) {
    show(reasonId, `not sent: the service cannot be reached (${error.message})`);
    return null;
  }
  const answer = await response.json().catch(() => ({}));
  if (response.status === 401) {
    // Kept, not deleted: the operator is told, and the next command asks for the right one.
    state.tokenRefused = true;
    show(reasonId, "refused (401): the stored token is not valid — the next command asks for it");
    return null;
  }
  if (!response.ok) {
    show(reasonId, `refused (${response.status}): ${describe(answer.detail)}`);
    return null;
  }
  show(reasonId, "accepted", true);
  return answer;
}

async function command(method, path, body, reasonId) {
  const bearer = await token();
  if (!bearer) {
    show(reasonId, "no token: the command was not sent");
    return null;
  }
  return send(method, path, body, reasonId, bearer);
}

// At once, with whatever token there is (none, a refused one): the page's origin suffices.
function abort() {
  closeTokenDialog();
  send("POST", "/api/abort", undefined, "abort-reason", storedToken());
}

// ---- telemetry -----------------------------------------------------------------------------
function connect() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const socket = new WebSocket(`${scheme}://${location.host}/api/telemetry`);
  state.socket = socket;
  socket.onopen = () => {
    // Beyond loopback the API wants the token first (a browser cannot set headers here).
    socket.send(JSON.stringify({ token: storedToken() }));
    state.retryMs = 500;
    setConnection(state.everConnected ? "reconnected" : "connected", "good");
    state.everConnected = true;
    state.stale = true;  // until the first message arrives
  };
  socket.onmessage = (event) => {
    state.telemetry = JSON.parse(event.data);
    state.lastMessageAt = performance.now();
    if (state.stale) {
      state.stale = false;
      markStale(false);
      setConnection(state.everLive ? "live again" : "connected", "good");
    }
    state.everLive = true;
    render(state.telemetry);
  };
  socket.onclose = async (event) => {
    state.stale = true;
    markStale(true);
    if (event.code === WS_TOKEN_REQUIRED) {
      setConnection("telemetry needs the token", "bad");
      if (storedToken()) state.tokenRefused = true;
      await token();
      setTimeout(connect, state.retryMs);
      state.retryMs = Math.min(state.retryMs * 2, 5000);
      return;
    }
    setConnection(`connection lost — reconnecting in ${(state.retryMs / 1000).toFixed(1)} s`, "bad");
    setTimeout(connect, state.retryMs);
    state.retryMs = Math.min(state.retryMs * 2, 5000);
  };
}

function setConnection(text, level) {
  const element = document.getElementById("connection");
  element.textContent = text;
  element.className = `lamp ${level}`;
}

function markStale(stale) {
  document.body.classList.toggle("stale", stale);
  document.getElementById("stale-note").textContent = stale ? "STALE: no live data" : "";
  if (stale) {
    for (const id of ["lamp-mocap", "lamp-uav1", "lamp-uav2", "lamp-tick"]) {
      document.getElementById(id).className = "lamp unknown";
    }
  }
}

function watchStaleness() {
  const stale = !state.telemetry || performance.now() - state.lastMessageAt > STALE_AFTER_MS;
  if (stale && !state.stale) {
    state.stale = true;
    markStale(true);
    if (state.socket && state.socket.readyState === WebSocket.OPEN) {
      setConnection("no telemetry", "warn");
    }
  }
}

// ---- rendering -----------------------------------------------------------------------------
const fmt = (v, digits = 2) => (v === null || v === undefined ? "–" : Number(v).toFixed(digits));
const deg = (rad) => (rad === null || rad === undefined ? "–" : `${(rad * 180 / Math.PI).toFixed(1)}°`);
const vec = (v) => (v && v.every((x) => x !== null) ? `(${v.map((x) => fmt(x)).join(", ")}) m` : "–");

function lamp(id, level) {
  document.getElementById(id).className = `lamp ${level}`;
}

const ago = (seconds) => (seconds < 90 ? `${Math.round(seconds)} s ago` : `${Math.round(seconds / 60)} min ago`);

function renderNotices(notices) {
  const items = notices.slice(-3).reverse().map((notice) => {
    const item = document.createElement("li");
    item.textContent = `${ago(notice.age_s)} — ${notice.message}`;
    return item;
  });
  document.getElementById("notices").replaceChildren(...items);
}

function render(t) {
  document.getElementById("mode").textContent = t.mode;
  document.getElementById("phase").textContent = t.phase;
  document.getElementById("controller").textContent = t.controller;
  for (const button of document.querySelectorAll("[data-controller]")) {
    button.classList.toggle("selected", button.dataset.controller === t.controller);
  }
  renderNotices(t.notices || []);
  lamp("lamp-mocap", t.mocap.healthy ? "good" : t.mocap.connected ? "warn" : "bad");
  t.uavs.forEach((uav, i) => lamp(`lamp-uav${i + 1}`, uav.connected ? "good" : "bad"));
  const tick = t.tick || {};
  lamp("lamp-tick", tick.missed_deadlines > 0 ? "warn" : tick.count > 0 ? "good" : "unknown");
  document.getElementById("bar-position").textContent = vec(t.bar.position);
  document.getElementById("bar-yaw").textContent = deg(t.bar.yaw);
  document.getElementById("bar-error").textContent = t.bar.error_m === null ? "–" : `${fmt(t.bar.error_m, 3)} m`;
  t.uavs.forEach((uav, i) => {
    document.getElementById(`uav${i + 1}-info`).textContent =
      `${vec(uav.position)} · ${uav.px4_mode} · ${t.armed[i] ? "armed" : "disarmed"}`;
    document.getElementById(`uav${i + 1}-text`).textContent = uav.status_text || "–";
  });
  document.getElementById("tick-info").textContent =
    `${tick.count ?? 0} (missed ${tick.missed_deadlines ?? 0}), compute p99 ${fmt(tick.compute_ms_p99)} ms`;
  renderSetpoints(t.setpoints);
  const now = t.time_s;
  pushHistory(plots.error, now, t.bar.error_m);
  pushHistory(plots.solve, now, t.plan ? t.plan.solve_ms : null);
  drawViews(t);
  drawPlot("error-plot", plots.error, now, "m");
  drawPlot("solve-plot", plots.solve, now, "ms");
}

function describeSetpoint(s) {
  return `(${s.bar_position.map((v) => fmt(v)).join(", ")}) m, yaw ${deg(s.bar_yaw)}, ` +
    `θl ${deg(s.theta_l)}, hold ${fmt(s.hold_s, 0)} s`;
}

function renderSetpoints(setpoints) {
  document.getElementById("active-setpoint").textContent =
    setpoints.active ? describeSetpoint(setpoints.active) : "none";
  const list = document.getElementById("queued-setpoints");
  list.replaceChildren(...setpoints.queued.map((s) => {
    const item = document.createElement("li");
    item.textContent = describeSetpoint(s);
    return item;
  }));
}

function pushHistory(series, t, value) {
  series.push([t, value]);
  while (series.length && series[0][0] < t - PLOT_SECONDS) series.shift();
}

function drawPlot(id, series, now, unit) {
  const canvas = document.getElementById(id);
  const g = canvas.getContext("2d");
  g.clearRect(0, 0, canvas.width, canvas.height);
  const values = series.map(([, v]) => v).filter((v) => v !== null);
  const top = Math.max(1e-3, ...values) * 1.1;
  g.fillStyle = "#8c98a4";
  g.fillText(`${fmt(top, 3)} ${unit}`, 4, 12);
  g.strokeStyle = "#4ea1ff";
  g.beginPath();
  let drawing = false;
  for (const [t, v] of series) {
    if (v === null) { drawing = false; continue; }
    const x = canvas.width * (1 - (now - t) / PLOT_SECONDS);
    const y = canvas.height * (1 - v / top);
    if (drawing) g.lineTo(x, y); else g.moveTo(x, y);
    drawing = true;
  }
  g.stroke();
}

function drawViews(t) {
  const arena = t.arena || { min: [-3, -3, 0], max: [3, 3, 3] };
  drawView("top-view", t, arena, 0, 1);
  drawView("side-view", t, arena, 0, 2);
}

function drawView(id, t, arena, a, b) {
  const canvas = document.getElementById(id);
  const g = canvas.getContext("2d");
  const span = [arena.max[a] - arena.min[a], arena.max[b] - arena.min[b]];
  const scale = Math.min(canvas.width / span[0], canvas.height / span[1]);
  const px = (p) => [(p[a] - arena.min[a]) * scale, canvas.height - (p[b] - arena.min[b]) * scale];
  g.clearRect(0, 0, canvas.width, canvas.height);
  g.strokeStyle = "#2a333c";
  g.strokeRect(0, canvas.height - span[1] * scale, span[0] * scale, span[1] * scale);
  const reference = t.reference;
  if (reference) {
    g.setLineDash([5, 4]);
    g.strokeStyle = "#9be39b";
    line(g, px, reference.bar_ends);
    reference.uav_positions.forEach((uav, i) => {
      dot(g, px(uav), 6, null, "#9be39b");
      line(g, px, [uav, reference.bar_ends[i]]);
    });
    g.setLineDash([]);
  }
  const ends = t.bar.ends;
  if (ends && ends.every((e) => e.every((v) => v !== null))) {
    g.lineWidth = 4;
    g.strokeStyle = "#f0a030";
    line(g, px, ends);
    g.lineWidth = 1;
    t.uavs.forEach((uav, i) => {
      if (uav.position.some((v) => v === null)) return;
      g.strokeStyle = "#6c7884";
      line(g, px, [uav.position, ends[i]]);
      dot(g, px(uav.position), 7, "#4ea1ff");
      g.fillStyle = "#e6e9ec";
      const [x, y] = px(uav.position);
      g.fillText(String(i + 1), x + 9, y - 6);
    });
  }
}

function line(g, px, points) {
  g.beginPath();
  points.forEach((p, i) => { const [x, y] = px(p); if (i) g.lineTo(x, y); else g.moveTo(x, y); });
  g.stroke();
}

function dot(g, [x, y], r, fill, stroke) {
  g.beginPath();
  g.arc(x, y, r, 0, 2 * Math.PI);
  if (fill) { g.fillStyle = fill; g.fill(); }
  if (stroke) { g.strokeStyle = stroke; g.stroke(); }
}

// ---- setpoint editor -----------------------------------------------------------------------
function setpointFromForm(form) {
  const v = (name) => form.elements[name].value;
  const radians = (d) => (Number(d) * Math.PI) / 180;
  const body = {
    bar_position: [Number(v("x")), Number(v("y")), Number(v("z"))],
    bar_yaw: radians(v("yaw")),
    theta_l: radians(v("theta_l")),
    hold_s: Number(v("hold")),
  };
  if (v("uav1") !== "" || v("uav2") !== "") {
    body.uav_yaw = [radians(v("uav1") || v("yaw")), radians(v("uav2") || v("yaw"))];
  }
  return body;
}

async function showEquilibrium() {
  const form = document.getElementById("setpoint-form");
  const thetaL = (Number(form.elements.theta_l.value) * Math.PI) / 180;
  const target = document.getElementById("equilibrium");
  try {
    const response = await fetch(`/api/equilibria?theta_l=${thetaL}`, { headers: authorization(storedToken()) });
    const body = await response.json();
    if (!response.ok) { target.textContent = describe(body.detail); return; }
    target.textContent = `θf ${deg(body.theta_f)} (Prop. 1); thrusts ${body.thrust.map((f) => fmt(f)).join(" / ")} N; ` +
      `cable tensions ${body.tension.map((f) => fmt(f)).join(" / ")} N`;
  } catch {
    target.textContent = "";
  }
}

// ---- wiring --------------------------------------------------------------------------------
function wire() {
  document.getElementById("abort").addEventListener("click", abort);
  // Escape aborts wherever the focus is (capture phase: before any input handles it), and
  // closes the token dialog if it is open.
  window.addEventListener("keydown", (event) => {
    if (event.key === "Escape") { event.preventDefault(); abort(); }
  }, true);
  document.getElementById("token-cancel").addEventListener("click", closeTokenDialog);
  for (const name of ["arm", "takeoff", "land", "disarm"]) {
    document.getElementById(name).addEventListener("click", () => command("POST", `/api/${name}`, undefined, "flight-reason"));
  }
  const confirm = document.getElementById("kill-confirm");
  const kill = document.getElementById("kill");
  confirm.addEventListener("change", () => { kill.disabled = !confirm.checked; });
  kill.addEventListener("click", async () => {
    await command("POST", "/api/kill", { confirm: true }, "kill-reason");
    confirm.checked = false;
    kill.disabled = true;
  });
  for (const button of document.querySelectorAll("[data-controller]")) {
    button.addEventListener("click", () => command("POST", "/api/mode", { controller: button.dataset.controller }, "controller-reason"));
  }
  const form = document.getElementById("setpoint-form");
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    command("POST", "/api/setpoints", setpointFromForm(form), "setpoint-reason");
  });
  form.elements.theta_l.addEventListener("input", showEquilibrium);
  document.getElementById("clear-setpoints").addEventListener("click", () => command("DELETE", "/api/setpoints", undefined, "setpoint-reason"));
  setInterval(watchStaleness, 100);
}

takeTokenFromAddress();
wire();
showEquilibrium();
connect();
