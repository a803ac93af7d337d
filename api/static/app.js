// uavbar-supervisor operator dashboard: telemetry over /api/telemetry, commands over REST.
// No build step. The token comes from the page address (#token=…, a fragment the browser
// never sends) or is asked for when a command needs it, and is kept for this browser tab only.
// ABORT never waits for it: the API takes an abort from this page's own origin without a
// valid token (docs/architecture.md, "The API's gate"), so it is sent at once, whatever the
// token and whatever dialog is open.
"use strict";

const STALE_AFTER_MS = 500;
const PLOT_SECONDS = 20;
const ACCEPTED_SHOWN_MS = 4000;  // an "accepted" clears itself; a refusal stays until the next try
const NOTICE_SHOWN_S = 120;  // older notices stay in the status (and the CLI), not on the page
const NOTICE_FRESH_S = 30;  // older ones are dimmed
const STALL_CAUSE_S = 2;  // a world stall this long before a mode began is named with it
const TICK_WINDOW_S = 10;  // the ticks lamp judges the loop by its last 10 s, not since start
const TOKEN_KEY = "uavbar-token";
const WS_TOKEN_REQUIRED = 4401;
const state = {
  telemetry: null, lastMessageAt: 0, socket: null, retryMs: 500,
  everConnected: false, everLive: false, stale: true, tokenRefused: false,
  lastCheckAt: 0, silentMs: 0, renderPending: false,
};
// [page time s, value] for the last PLOT_SECONDS; null breaks the line (no live data).
const plots = { error: [], solve: [], battery: [[], []] };  // battery: one series per UAV
const COLOURS = { bar: "#f0a030", uav: "#4ea1ff", ref: "#9be39b", path: "#ff5fd2", grid: "#2a333c", edge: "#5c6a78", muted: "#8c98a4", text: "#e6e9ec" };
// Each UAV's line in the battery plot, UAV 1's first.
const UAV_COLOURS = ["#4ea1ff", "#c58bff", "#5fd3c6", "#f27a8f", "#e0d25a", "#9fb7ff", "#ff9f5a", "#7be07b"];
const tickHistory = [];  // [page time s, tick count, missed deadlines], the last TICK_WINDOW_S

// What each mode that is not normal flight means, in words; level "bad" or "warn".
const DANGER_MODES = {
  abort: { level: "bad", title: "ABORT", what: "coordinated landing: the bar is set down, then the vehicles disarm" },
  px4_landing: { level: "bad", title: "PX4 LANDING", what: "the vehicles are PX4's until both are heard landed and disarmed (each lands on its own); the supervisor sends nothing" },
  killed: { level: "bad", title: "KILLED", what: "the motors were stopped" },
  landing: { level: "warn", title: "LANDING", what: "the bar is set down, then the vehicles disarm" },
};
// Who asks for these modes when no safety monitor did (no notice younger than the mode).
const ASKED_BY = {
  abort: "asked for with ABORT (a dashboard, the CLI or REST)",
  landing: "asked for with Land (a dashboard, the CLI, REST, or serve stopping)",
  killed: "asked for with KILL",
  px4_landing: "",
};
const MODE_CAUSES = new Set(["abort", "land_other", "blind", "process"]);  // notice kinds
// How a flight can end other than by a landing: said, once disarmed, until the next arm.
const ENDINGS = { abort: "an abort", px4_landing: "PX4's own landing", killed: "a kill" };
// Notice kinds that end a flight in "abort" (the flight process keeps the last 20 notices,
// with their ages): a page opened after such a flight finds why there. How it ended is the
// status's ``last_flight`` (an operator's ABORT leaves no notice).
const ABORT_NOTICES = new Set(["abort", "land_other"]);
// An abort's coordinated landing is over well within this [s]: a notice this much older
// than the disarm belongs to an earlier flight.
const ABORT_LANDING_MAX_S = 120;
// What the page knows of the last flight's ending: ``mode`` one of ENDINGS (null: none
// seen since the last arm) and ``why``; ``checked`` once the first message was read.
const lastFlight = { mode: null, why: "", checked: false };

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
  const shown = (element.dataset.shown = String(Number(element.dataset.shown || 0) + 1));
  if (ok) {
    setTimeout(() => { if (element.dataset.shown === shown) element.textContent = ""; }, ACCEPTED_SHOWN_MS);
  }
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

// The simulated world back in its resting pose; its answer says whether the motion capture
// tracks the bodies there and whether an arm would be refused now.
async function resetWorld() {
  const answer = await command("POST", "/api/sim/reset", undefined, "flight-reason");
  if (!answer) return;
  const tracked = answer.tracked
    ? "the motion capture tracks the bodies at rest"
    : "the motion capture does not track the bodies at rest yet";
  const arm = answer.arm_blocked_by ? `an arm would be refused: ${answer.arm_blocked_by}` : "an arm would be accepted";
  show("flight-reason", `world reset: ${tracked}; ${arm}`, answer.tracked && !answer.arm_blocked_by);
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
    state.silentMs = 0;
    if (state.stale) {
      state.stale = false;
      markStale(false);
      setConnection(state.everLive ? "live again" : "connected", "good");
    }
    state.everLive = true;
    if (!state.renderPending) {
      state.renderPending = true;
      requestAnimationFrame(renderLatest);
    }
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

// Drawn once per frame, the latest message only: a page that cannot keep up at the
// telemetry's rate (a busy laptop, software WebGL) draws less often instead of queueing
// work behind which clicks, ABORT's included, would wait.
function renderLatest() {
  state.renderPending = false;
  if (state.stale) return;  // the stream ended after the message: markStale has drawn that
  render(state.telemetry);
  window.dispatchEvent(new CustomEvent("uavbar:telemetry", { detail: state.telemetry }));
}

function setConnection(text, level) {
  const element = document.getElementById("connection");
  element.textContent = text;
  element.className = `lamp ${level}`;
  element.title = `the telemetry stream (WebSocket) from the service: ${text}`;
}

function markStale(stale) {
  document.body.classList.toggle("stale", stale);
  document.getElementById("stale-note").textContent = stale ? "STALE: no live data" : "";
  if (stale) {
    for (const element of document.querySelectorAll(".lamps .lamp")) {
      lamp(element.id, "unknown", "no live data: the telemetry stream is not arriving");
    }
    tickHistory.length = 0;
  }
  renderBanner();
}

// Every 100 ms. Silence is counted in the page's own running time: a check comes late when
// the page itself stalled (the 3D view's shaders compiling on a busy machine), and the
// messages that arrived meanwhile are still queued, so a check counts at most 150 ms. A
// page that keeps stalling still says "stale", later.
function watchStaleness() {
  const checkedAt = performance.now();
  state.silentMs += Math.min(checkedAt - state.lastCheckAt, 150);
  state.lastCheckAt = checkedAt;
  const stale = !state.telemetry || state.silentMs > STALE_AFTER_MS;
  if (stale && !state.stale) {
    state.stale = true;
    markStale(true);
    if (state.socket && state.socket.readyState === WebSocket.OPEN) {
      setConnection("no telemetry", "warn");
    }
  }
  if (state.stale) {
    renderBanner();  // the age of what is shown keeps counting
    const now = performance.now() / 1000;
    for (const series of [plots.error, plots.solve, ...plots.battery]) pushHistory(series, now, null);
    drawPlots(now);
  }
}

// ---- rendering -----------------------------------------------------------------------------
const fmt = (v, digits = 2) => (v === null || v === undefined ? "–" : Number(v).toFixed(digits));
const deg = (rad) => (rad === null || rad === undefined ? "–" : `${(rad * 180 / Math.PI).toFixed(1)}°`);
const vec = (v) => (v && v.every((x) => x !== null) ? `(${v.map((x) => fmt(x)).join(", ")}) m` : "–");

// Written only on a change: a write of the same text still costs the page a layout and a
// paint, 25 times a second.
function setText(id, text) {
  const element = document.getElementById(id);
  if (element.textContent !== text) element.textContent = text;
}

function replaceItems(id, items) {
  const list = document.getElementById(id);
  const key = items.map((item) => `${item.className}|${item.textContent}`).join("\n");
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  list.replaceChildren(...items);
}

// The page is written for two UAVs (the paper's); a status that lists more adds each one's
// lamp, column in the vehicles table, yaw field and battery line, made from UAV 2's.
function ensureVehicles(count) {
  for (let n = 3; n <= count; n += 1) {
    if (document.getElementById(`lamp-uav${n}`)) continue;
    const renamed = (element) => {
      const copy = element.cloneNode(true);
      for (const node of [copy, ...copy.querySelectorAll("*")]) {
        for (const attribute of ["id", "data-testid", "name", "class"]) {
          const value = node.getAttribute(attribute);
          if (value) node.setAttribute(attribute, value.replace("uav2", `uav${n}`).replace("link2", `link${n}`));
        }
      }
      return copy;
    };
    const previousLamp = document.getElementById(`lamp-uav${n - 1}`);
    const newLamp = renamed(document.getElementById("lamp-uav2"));
    newLamp.textContent = `UAV ${n}`;
    newLamp.title = `vehicle ${n} link: no data yet`;
    previousLamp.after(newLamp);
    for (const row of document.querySelectorAll("table.vehicles tr")) {
      const uav2Cell = row.children[2];  // every new column is a copy of UAV 2's
      const added = uav2Cell.tagName === "TH" ? document.createElement("th") : renamed(uav2Cell);
      if (uav2Cell.tagName === "TH") added.textContent = `UAV ${n}`;
      else added.textContent = "–";
      row.appendChild(added);
    }
    const previousYaw = document.querySelector(`#setpoint-form input[name="uav${n - 1}"]`);
    previousYaw.after(" ", renamed(document.querySelector('#setpoint-form input[name="uav2"]')));
    plots.battery.push([]);
  }
}

function lamp(id, level, title) {
  const element = document.getElementById(id);
  const className = `lamp ${level}`;
  if (element.className !== className) element.className = className;
  if (element.title !== title) element.title = title;
}

const ago = (seconds) => (seconds < 90 ? `${Math.round(seconds)} s ago` : `${Math.round(seconds / 60)} min ago`);

function renderNotices(notices) {
  const recent = notices.filter((notice) => notice.age_s < NOTICE_SHOWN_S);
  const items = recent.slice(-3).reverse().map((notice) => {
    const item = document.createElement("li");
    item.textContent = `${ago(notice.age_s)} — ${notice.message}`;
    item.classList.toggle("old", notice.age_s >= NOTICE_FRESH_S);
    return item;
  });
  replaceItems("notices", items);
}

const noticeKind = (message) => message.split(":", 1)[0];

// The embedded simulated world's latest stall (a busy computer held it, and its mocap and
// vehicles paused with it), while notices are still shown; null: none, or no such world.
function recentWorldStall(world) {
  const stalls = world && world.stalls;
  if (!stalls || !stalls.count || stalls.last_age_s === null) return null;
  return stalls.last_age_s < NOTICE_SHOWN_S ? stalls : null;
}

function renderWorldStalls(world) {
  const stalls = recentWorldStall(world);
  if (!stalls) {
    setText("world-stalls", "");
    return;
  }
  const times = stalls.count === 1 ? "once" : `${stalls.count} times`;
  setText("world-stalls",
    `This computer stalled the simulated world ${times} (busy): the last for ${fmt(stalls.last_ms, 0)} ms ` +
    `${ago(stalls.last_age_s)}, the worst ${fmt(stalls.worst_ms, 0)} ms. Its mocap and vehicles paused ` +
    "with it: a gap then was this computer's, not the lab's.");
}

// A stall of the world shortly before the mode began: the likely cause, said with it.
function stallBeforeMode(t) {
  const stalls = recentWorldStall(t.world);
  if (!stalls || t.mode_for_s === undefined) return null;
  return stalls.last_age_s <= t.mode_for_s + STALL_CAUSE_S
    ? `the simulated world had stalled ${fmt(stalls.last_ms, 0)} ms just before (this computer was busy)`
    : null;
}

// The notices that put the system in its mode: those no older than the mode itself.
function modeCauses(t) {
  const since = (t.mode_for_s ?? Infinity) + 0.5;  // the same tick, give or take a message
  return (t.notices || [])
    .filter((notice) => notice.age_s <= since && MODE_CAUSES.has(noticeKind(notice.message)))
    .map((notice) => notice.message);
}

// The danger the last telemetry shows (null: normal): a mode that is not normal flight and
// why, the safety monitors' faults of the last tick, and whether all of it is stale.
function danger(t) {
  if (!t) return null;
  const mode = DANGER_MODES[t.mode];
  const faults = t.faults || [];
  if (!mode && !faults.length) return null;
  const parts = [];
  if (mode) {
    parts.push(mode.what);
    const causes = modeCauses(t);
    parts.push(causes.length ? `why: ${causes.join("; ")}` : ASKED_BY[t.mode]);
    parts.push(stallBeforeMode(t));
  }
  if (faults.length) parts.push(`faults now: ${faults.join("; ")}`);
  return {
    level: mode ? mode.level : "warn",
    title: mode ? mode.title : "FAULT",
    text: parts.filter(Boolean).join(" — "),
  };
}

function renderBanner() {
  const banner = document.getElementById("banner");
  const shown = danger(state.telemetry);
  const age = (performance.now() - state.lastMessageAt) / 1000;
  const staleNote = state.telemetry ? `no live data: what is shown is ${ago(age).replace(" ago", "")} old` : "no live data yet";
  let level = null, title = "", text = "";
  if (shown) {
    ({ level, title, text } = shown);
    if (state.stale) text += ` (last known; ${staleNote})`;
  } else if (state.stale) {
    level = "warn";
    title = "NO LIVE DATA";
    text = staleNote;
  }
  banner.hidden = level === null;
  const className = `banner ${level || ""}`;
  if (banner.className !== className) banner.className = className;
  setText("banner-title", title);
  setText("banner-text", text);
  const dangerLevel = shown ? shown.level : "";
  if (document.body.dataset.danger !== dangerLevel) document.body.dataset.danger = dangerLevel;
}

function mocapLamp(m) {
  const rate = `${fmt(m.rate_hz, 0)} frames/s`;
  const meaning = "motion capture (green: every body measured and fresh; yellow: streaming, but the estimate is not healthy; red: no stream)";
  if (m.healthy) return ["good", `${meaning}. Now: healthy, ${rate}`];
  if (m.connected) {
    const bodies = m.unhealthy && m.unhealthy.length ? `: ${m.unhealthy.join(", ")}` : "";
    return ["warn", `${meaning}. Now: connected, ${rate}, not healthy${bodies}`];
  }
  return ["bad", `${meaning}. Now: not connected`];
}

function uavLamp(uav, i) {
  const meaning = `vehicle ${i} link (green: PX4's heartbeat heard; red: lost)`;
  return uav.connected
    ? ["good", `${meaning}. Now: connected, PX4 mode ${uav.px4_mode}`]
    : ["bad", `${meaning}. Now: LOST — the values from this link are stale`];
}

// Judged on the last TICK_WINDOW_S: a deadline missed at start-up does not keep it yellow.
function tickLamp(tick) {
  const now = performance.now() / 1000;
  const last = tickHistory[tickHistory.length - 1];
  if (last && tick.count < last[1]) tickHistory.length = 0;  // a restarted flight process
  tickHistory.push([now, tick.count ?? 0, tick.missed_deadlines ?? 0]);
  while (tickHistory.length > 1 && tickHistory[0][0] < now - TICK_WINDOW_S) tickHistory.shift();
  const [since, count, missed] = tickHistory[0];
  const span = now - since;
  const ticks = (tick.count ?? 0) - count;
  const late = (tick.missed_deadlines ?? 0) - missed;
  const meaning = "20 ms control loop (green: every tick on time; yellow: ticks missed their deadline; red: no ticks)";
  const total = `; ${tick.missed_deadlines ?? 0} missed of ${tick.count ?? 0} since start`;
  if (span >= 1 && ticks === 0) return ["bad", `${meaning}. Now: no tick for ${span.toFixed(0)} s`];
  if (late > 0) return ["warn", `${meaning}. Now: ${late} of ${ticks} missed in the last ${span.toFixed(0)} s${total}`];
  if (ticks > 0) return ["good", `${meaning}. Now: on time for the last ${span.toFixed(0)} s${total}`];
  return ["unknown", `${meaning}. Now: waiting for ticks`];
}

// Remembered from the telemetry as it comes: a danger mode seen with a vehicle armed is how
// the flight ended (its causes are those of the mode); the next arm forgets it. Not the
// px4_landing a flight process starts in, its vehicles disarmed: no flight ended there. A
// page opened while disarmed takes the flight process's ``last_flight``, and why from an
// abort's notices just before the disarm (without one, it was asked for).
function trackLastFlight(t) {
  const firstMessage = !lastFlight.checked;
  lastFlight.checked = true;
  if (t.mode === "armed") {
    lastFlight.mode = null;
    lastFlight.why = "";
  } else if (ENDINGS[t.mode] && (t.mode === "killed" || t.armed.some(Boolean))) {
    const causes = modeCauses(t);
    if (lastFlight.mode !== t.mode) lastFlight.why = "";
    lastFlight.mode = t.mode;
    if (causes.length) lastFlight.why = causes.join("; ");
    else if (!lastFlight.why) lastFlight.why = ASKED_BY[t.mode] || "";
  } else if (firstMessage && t.mode === "disarmed" && t.mode_for_s !== undefined) {
    const before = (t.notices || []).filter((notice) => ABORT_NOTICES.has(noticeKind(notice.message))
      && notice.age_s >= t.mode_for_s && notice.age_s - t.mode_for_s <= ABORT_LANDING_MAX_S);
    const ended = t.last_flight ? t.last_flight.ended_in : (before.length ? "abort" : null);
    if (ENDINGS[ended]) {
      lastFlight.mode = ended;
      const causes = ended === "abort" ? before.map((notice) => notice.message) : [];
      lastFlight.why = causes.join("; ") || ASKED_BY[ended] || "";
    }
  }
}

function renderLastFlight(t) {
  const element = document.getElementById("last-flight");
  const shown = t.mode === "disarmed" && lastFlight.mode !== null;
  element.hidden = !shown;
  const ended = shown ? lastFlight.mode : "";
  if (element.dataset.ended !== ended) element.dataset.ended = ended;
  const since = t.mode_for_s === undefined ? "" : ` (disarmed ${ago(t.mode_for_s)})`;
  setText("last-flight-title", shown ? `Last flight ended in ${ENDINGS[lastFlight.mode]}` : "");
  setText("last-flight-text", shown ? `${since}: ${lastFlight.why || "why is not known"} — shown until the next arm` : "");
}

// The mode's look: disarmed "safe" (grey), armed or disarming on the ground "armed" (amber), the danger
// modes their level; ``body[data-flight]`` says which of disarmed, armed, flying, danger or
// "ended-MODE" (disarmed after a flight that ended in MODE) the page shows.
function renderModeLook(t) {
  const modeLevel = DANGER_MODES[t.mode] ? DANGER_MODES[t.mode].level
    : { disarmed: "safe", armed: "armed", disarming: "armed" }[t.mode] || "";
  const modeElement = document.getElementById("mode");
  if (modeElement.dataset.level !== modeLevel) modeElement.dataset.level = modeLevel;
  const title = { disarmed: "disarmed: the vehicles' motors are off",
    armed: "armed on the ground: the motors are live — take off or disarm",
    disarming: "landed: the vehicles are being disarmed, a motor may still be live" }[t.mode] || "";
  if (modeElement.title !== title) modeElement.title = title;
  let flight = "flying";
  if (t.mode === "disarmed") flight = lastFlight.mode ? `ended-${lastFlight.mode}` : "disarmed";
  else if (t.mode === "armed" || t.mode === "disarming") flight = "armed";
  else if (DANGER_MODES[t.mode] && DANGER_MODES[t.mode].level === "bad") flight = "danger";
  if (document.body.dataset.flight !== flight) document.body.dataset.flight = flight;
}

// The force observer's loads in one line: their sizes, and any held at its bound.
function loadsText(loads) {
  if (!loads) return "observer off";
  const size = (v) => fmt(Math.hypot(...v.map((c) => c ?? 0)), 2);
  const uavs = loads.uav_forces_n.map(size).join(" / ");
  const bound = loads.at_bound.length ? ` — at bound: ${loads.at_bound.join(", ")}` : "";
  return `bar ${size(loads.bar_force_n)} N, ${size(loads.bar_torque_nm)} N m; UAVs ${uavs} N${bound}`;
}

function render(t) {
  setText("mode", t.mode);
  trackLastFlight(t);
  renderModeLook(t);
  renderLastFlight(t);
  setText("phase", t.phase);
  setText("controller", t.controller);
  for (const button of document.querySelectorAll("[data-controller]")) {
    button.classList.toggle("selected", button.dataset.controller === t.controller);
  }
  renderNotices(t.notices || []);
  renderWorldStalls(t.world);
  renderBanner();
  ensureVehicles(t.uavs.length);
  lamp("lamp-mocap", ...mocapLamp(t.mocap));
  t.uavs.forEach((uav, i) => lamp(`lamp-uav${i + 1}`, ...uavLamp(uav, i + 1)));
  const tick = t.tick || {};
  lamp("lamp-tick", ...tickLamp(tick));
  // In flight, arming is refused for being in flight: said only where arming is the question.
  const armQuestion = ["disarmed", "disarming", "px4_landing", "killed"].includes(t.mode) && t.arm_blocked_by;
  setText("arm-blocked", armQuestion ? `Arm would be refused now: ${t.arm_blocked_by}` : "");
  document.getElementById("arm").classList.toggle("blocked", Boolean(t.arm_blocked_by));
  setText("log-stopped", t.log_stopped ? `Flight log: ${t.log_stopped}` : "");
  // Reset: only where the simulator offers one, and only while disarmed (it is refused
  // while a vehicle is armed).
  const reset = document.getElementById("reset");
  const canReset = Boolean(t.world && t.world.embedded) && t.mode === "disarmed" && !t.armed.some(Boolean);
  if (reset.hidden === canReset) reset.hidden = !canReset;
  // Greyed: what comes from a source that is not live (the mocap's estimate, a lost link).
  greyed(".mocap-value", !t.mocap.healthy);
  setText("bar-position", vec(t.bar.position));
  setText("bar-yaw", deg(t.bar.yaw));
  setText("bar-error", t.bar.error_m === null ? "–" : `${fmt(t.bar.error_m, 3)} m`);
  setText("loads", loadsText(t.loads));
  t.uavs.forEach((uav, i) => {
    const n = i + 1;
    greyed(`.link${n}-value`, !uav.connected);
    setText(`uav${n}-position`, vec(uav.position).replace(" m", ""));
    setText(`uav${n}-px4`, uav.connected ? uav.px4_mode : `${uav.px4_mode} (link lost)`);
    setText(`uav${n}-armed`, t.armed[i] ? "armed" : "disarmed");
    setText(`uav${n}-text`, uav.status_text || "–");
    setText(`uav${n}-battery`, uav.battery_v === null || uav.battery_v === undefined ? "–" : `${fmt(uav.battery_v, 1)} V`);
  });
  renderAgents(t.agents);
  setText("tick-info", `${tick.count ?? 0} (missed ${tick.missed_deadlines ?? 0}), compute p99 ${fmt(tick.compute_ms_p99)} ms`);
  renderSetpoints(t.setpoints);
  renderPath(t.path);
  const now = performance.now() / 1000;
  pushHistory(plots.error, now, t.bar.error_m);
  pushHistory(plots.solve, now, t.plan ? t.plan.solve_ms : null);
  t.uavs.forEach((uav, i) => pushHistory(plots.battery[i], now, uav.connected ? uav.battery_v : null));
  drawViews(t);
  drawPlots(now);
}

function agentText(agent) {
  if (agent.pid === null) return "never heard";
  const where = `${agent.host} pid ${agent.pid}`;
  if (!agent.alive) return `lost (${where}, heard ${ago(agent.last_message_age_s ?? 0)})`;
  return `${where}, ${fmt(agent.link_latency_ms, 1)} ms`;
}

// Shown only when each vehicle has an agent process of its own (status.agents not null).
function renderAgents(agents) {
  const row = document.getElementById("agent-row");
  const shown = Array.isArray(agents);
  if (row.hidden === shown) row.hidden = !shown;
  for (const agent of agents || []) {
    setText(`uav${agent.vehicle}-agent`, agentText(agent));
    document.getElementById(`uav${agent.vehicle}-agent`).classList.toggle("lost", !agent.alive);
  }
}

function drawPlots(now) {
  drawPlot("error-plot", [{ points: plots.error, colour: COLOURS.uav }], now, "m", true);
  drawPlot("solve-plot", [{ points: plots.solve, colour: COLOURS.uav }], now, "ms", true);
  drawPlot("battery-plot", plots.battery.map((points, i) => (
    { points, colour: UAV_COLOURS[i % UAV_COLOURS.length], label: `UAV ${i + 1}` }
  )), now, "V", false);
}

function greyed(selector, stale) {
  for (const element of document.querySelectorAll(selector)) element.classList.toggle("stale-value", stale);
}

function describeSetpoint(s) {
  return `(${s.bar_position.map((v) => fmt(v)).join(", ")}) m, yaw ${deg(s.bar_yaw)}, ` +
    `θl ${deg(s.theta_l)}, hold ${fmt(s.hold_s, 0)} s`;
}

function renderSetpoints(setpoints) {
  setText("active-setpoint", setpoints.active ? describeSetpoint(setpoints.active) : "none");
  replaceItems("queued-setpoints", setpoints.queued.map((s) => {
    const item = document.createElement("li");
    item.textContent = describeSetpoint(s);
    return item;
  }));
}

// The active setpoint's path: its length, waypoints and how far along it the reference is.
function renderPath(path) {
  if (!path) {
    setText("path-progress", "");
    return;
  }
  let progress = "not begun (the bar is brought to its start)";
  if (path.elapsed_s !== null && path.elapsed_s >= path.duration_s) progress = "flown, its end held";
  else if (path.elapsed_s !== null) progress = `${fmt(path.elapsed_s, 1)} / ${fmt(path.duration_s, 1)} s`;
  setText("path-progress", `Path ${fmt(path.length_m)} m through ${path.waypoints.length} waypoints ` +
    `in ${fmt(path.duration_s, 1)} s: ${progress}`);
}

function pushHistory(series, t, value) {
  if (value === undefined) value = null;
  series.push([t, value]);
  while (series.length && series[0][0] < t - PLOT_SECONDS) series.shift();
}

// A canvas drawn at its laid-out size (CSS pixels × the device's pixel ratio); the context
// works in CSS pixels.
function fitCanvas(canvas) {
  const ratio = window.devicePixelRatio || 1;
  const width = Math.max(1, Math.round(canvas.clientWidth * ratio));
  const height = Math.max(1, Math.round(canvas.clientHeight * ratio));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  const g = canvas.getContext("2d");
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.clearRect(0, 0, canvas.clientWidth, canvas.clientHeight);
  g.font = "11px system-ui, sans-serif";
  return [g, canvas.clientWidth, canvas.clientHeight];
}

// Round steps (1, 2, 5 × 10^k) for about ``count`` ticks over [low, high].
function ticks(low, high, count) {
  const raw = (high - low) / count;
  const magnitude = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * magnitude).find((m) => m >= raw);
  const first = Math.ceil(low / step) * step;
  const values = [];
  for (let v = first; v <= high + step * 1e-9; v += step) values.push(Number(v.toPrecision(12)));
  return values;
}

// Time on x (the last PLOT_SECONDS, "now" at the right), the value on y with its unit.
function drawPlot(id, series, now, unit, fromZero) {
  const [g, width, height] = fitCanvas(document.getElementById(id));
  const bottom = 16, top = 6, right = 8;
  const values = series.flatMap((s) => s.points.map(([, v]) => v)).filter((v) => v !== null);
  let low = fromZero ? 0 : Math.min(...values), high = Math.max(...values);
  if (!values.length) { low = 0; high = 1; }
  if (high - low < 1e-3) { low -= fromZero ? 0 : 0.05; high += 0.05; }
  const pad = (high - low) * 0.1;
  high += pad;
  if (!fromZero) low -= pad;
  const yTicks = ticks(low, high, 3);
  const digits = Math.max(0, -Math.floor(Math.log10(yTicks[1] - yTicks[0] || 1)));
  const labels = yTicks.map((v) => `${v.toFixed(digits)} ${unit}`);
  const left = 8 + Math.max(...labels.map((label) => g.measureText(label).width));
  const x = (t) => left + (width - left - right) * (1 - (now - t) / PLOT_SECONDS);
  const y = (v) => top + (height - top - bottom) * (1 - (v - low) / (high - low));
  g.strokeStyle = COLOURS.grid;
  g.fillStyle = COLOURS.muted;
  g.lineWidth = 1;
  g.textAlign = "right";
  g.textBaseline = "middle";
  yTicks.forEach((v, i) => {
    g.beginPath(); g.moveTo(left, y(v)); g.lineTo(width - right, y(v)); g.stroke();
    g.fillText(labels[i], left - 4, y(v));
  });
  g.textAlign = "center";
  g.textBaseline = "top";
  for (let ago = PLOT_SECONDS; ago >= 0; ago -= 5) {
    const at = x(now - ago);
    g.beginPath(); g.moveTo(at, top); g.lineTo(at, height - bottom); g.stroke();
    g.fillText(ago ? `−${ago} s` : "now", Math.min(at, width - right - 10), height - bottom + 3);
  }
  g.save();
  g.beginPath(); g.rect(left, top, width - left - right, height - top - bottom); g.clip();
  series.forEach(({ points, colour }, i) => {
    g.lineWidth = 1.5 * (series.length - i);  // wider first: equal values stay visible
    g.strokeStyle = colour;
    g.beginPath();
    let drawing = false;
    for (const [t, v] of points) {
      if (v === null) { drawing = false; continue; }
      if (drawing) g.lineTo(x(t), y(v)); else g.moveTo(x(t), y(v));
      drawing = true;
    }
    g.stroke();
  });
  g.restore();
  g.textAlign = "left";
  series.filter((s) => s.label).forEach((s, i) => {
    g.fillStyle = s.colour;
    g.fillText(s.label, left + 6 + i * 48, top + 2);
  });
}

function drawViews(t) {
  const arena = t.arena || { min: [-3, -3, 0], max: [3, 3, 3] };
  drawView("top-view", t, arena, 0, 1);
  drawView("side-view", t, arena, 0, 2);
}

// The whole arena, scaled to fit the canvas and centred, ``a`` → right, ``b`` ↑: its
// outline, a 1 m grid, and the metres at both ends of each axis. What was drawn is kept in
// the canvas's ``data-arena`` (the outline in CSS pixels from its top left, and the bounds
// [m] it stands for), for the page's tests to check against the window.
const VIEW_INSET_PX = 1;  // the outline (2 px wide) drawn inside the canvas

function drawView(id, t, arena, a, b) {
  const canvas = document.getElementById(id);
  const [g, width, height] = fitCanvas(canvas);
  const span = [arena.max[a] - arena.min[a], arena.max[b] - arena.min[b]];
  const scale = Math.min((width - 2 * VIEW_INSET_PX) / span[0], (height - 2 * VIEW_INSET_PX) / span[1]);
  const x0 = (width - span[0] * scale) / 2, y0 = (height + span[1] * scale) / 2;
  const [x1, y1] = [x0 + span[0] * scale, y0 - span[1] * scale];
  const px = (p) => [x0 + (p[a] - arena.min[a]) * scale, y0 - (p[b] - arena.min[b]) * scale];
  g.strokeStyle = "#1c232a";  // a 1 m grid, labelled along the bottom and left edges
  g.lineWidth = 1;
  g.fillStyle = COLOURS.muted;
  g.textBaseline = "alphabetic";
  // Each x label right of its line; one that would leave the arena, left of it; one that
  // would then touch its neighbour is left out (the end of the arena is always labelled).
  const xLabels = [];
  for (let v = Math.ceil(arena.min[a]); v <= arena.max[a]; v += 1) {
    const [x] = px({ [a]: v, [b]: arena.min[b] });
    g.beginPath(); g.moveTo(x, y0); g.lineTo(x, y1); g.stroke();
    const text = `${v} m`, textWidth = g.measureText(text).width;
    const atEnd = x + 3 + textWidth > x1 - 2;
    xLabels.push({ text, x: atEnd ? x - 3 : x + 3, from: atEnd ? x - 3 - textWidth : x + 3, atEnd });
  }
  xLabels.forEach((label, i) => {
    const next = xLabels[i + 1];
    if (next && next.atEnd && label.from + g.measureText(label.text).width + 6 > next.from) return;
    g.textAlign = label.atEnd ? "right" : "left";
    g.fillText(label.text, label.x, y0 - 4);
  });
  g.textAlign = "left";
  for (let v = Math.ceil(arena.min[b]); v <= arena.max[b]; v += 1) {
    const [, y] = px({ [a]: arena.min[a], [b]: v });
    g.beginPath(); g.moveTo(x0, y); g.lineTo(x1, y); g.stroke();
    if (v === arena.min[b]) continue;  // the corner has the other axis's label
    g.fillText(`${v} m`, x0 + 4, y - y1 < 14 ? y + 13 : y - 3);  // the top one, below its line
  }
  g.strokeStyle = COLOURS.edge;
  g.lineWidth = 2;
  g.strokeRect(x0, y1, x1 - x0, y0 - y1);
  const tenth = (v) => Math.round(v * 10) / 10;  // written on a change only: a tenth of a pixel
  const key = JSON.stringify({
    left: tenth(x0), top: tenth(y1), right: tenth(x1), bottom: tenth(y0),
    min: [arena.min[a], arena.min[b]], max: [arena.max[a], arena.max[b]],
  });
  if (canvas.dataset.arena !== key) canvas.dataset.arena = key;
  if (t.path) {  // under the reference, which moves along it
    g.lineWidth = 2;
    g.strokeStyle = COLOURS.path;
    line(g, px, t.path.points);
    t.path.waypoints.forEach((point) => dot(g, px(point), 3, null, COLOURS.path));
  }
  const reference = t.reference;
  if (reference) {
    g.setLineDash([5, 4]);
    g.strokeStyle = "#9be39b";
    line(g, px, outline(reference.bar_ends));
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
    line(g, px, outline(ends));
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

// A payload's outline: the bar's two ends, or the closed polygon of three or more.
const outline = (ends) => (ends.length > 2 ? [...ends, ends[0]] : ends);

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
  const uavYaws = [...form.querySelectorAll('input[name^="uav"]')].map((input) => input.value);
  if (uavYaws.some((yaw) => yaw !== "")) body.uav_yaw = uavYaws.map((yaw) => radians(yaw || v("yaw")));
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
    const refusals = body.refusals || [];
    target.textContent = `θf ${deg(body.theta_f)} (Prop. 1); thrusts ${body.thrust.map((f) => fmt(f)).join(" / ")} N; ` +
      `cable tensions ${body.tension.map((f) => fmt(f)).join(" / ")} N` +
      (refusals.length ? ` — a setpoint here would be refused: ${refusals.join("; ")}` : "");
    target.classList.toggle("blocked", refusals.length > 0);
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
  document.getElementById("reset").addEventListener("click", resetWorld);
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

// The header's height, for the views' (they fill the window below it); a resize redraws.
function watchLayout() {
  const top = document.getElementById("top");
  const redraw = () => {
    document.documentElement.style.setProperty("--top-h", `${top.offsetHeight}px`);
    if (state.telemetry) drawViews(state.telemetry);
    drawPlots(performance.now() / 1000);
  };
  new ResizeObserver(redraw).observe(top);
  new ResizeObserver(redraw).observe(document.getElementById("views"));
  new ResizeObserver(redraw).observe(document.getElementById("live-panel"));
}

takeTokenFromAddress();
watchLayout();
wire();
showEquilibrium();
connect();
