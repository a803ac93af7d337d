// The 3D view: the arena (floor grid every 0.5 m, 1 m lines labelled, its bounds), the bar,
// the cables, the UAVs, the reference (dashed) and the active path, in the arena's frame
// (z up), drawn with three.js (vendor/three.module.min.js, r170, MIT: vendor/three-LICENSE.txt).
// A module of its own, fed by app.js's "uavbar:telemetry" events: if WebGL or the library
// is missing, the view says so and the rest of the page, ABORT first, works as before.
// Drag to turn, wheel to zoom, double-click for the first view; at zoom 1 the whole arena,
// its labels included, is in sight whatever the turn. It draws when the camera
// moves, on telemetry at most TELEMETRY_DRAWS_HZ (without a GPU, WebGL is drawn in software:
// at 25 Hz it took a core's half, and the page's clicks waited), and not at all while it is
// scrolled out of sight.
import * as THREE from "/static/vendor/three.module.min.js";

const COLOURS = { bar: 0xf0a030, uav: 0x4ea1ff, cable: 0x9aa4ad, ref: 0x9be39b, path: 0xff5fd2, grid: 0x2a333c, major: 0x46525e, box: 0x5c6a78 };
const HOME = { azimuth: -Math.PI / 3, elevation: Math.PI / 7, zoom: 1 };
const FOV_DEG = 40;
const TELEMETRY_DRAWS_HZ = 10;
const LABEL_M = 0.6;  // the metre labels reach this far outside the arena (0.4 m off, 0.2 m wide)
const FIT_MARGIN = 1.04;  // a little room around the arena at zoom 1

function label(text, colour = "#8c98a4", height = 0.22) {
  const canvas = document.createElement("canvas");
  const g = canvas.getContext("2d");
  g.font = "48px system-ui, sans-serif";
  canvas.width = Math.ceil(g.measureText(text).width) + 8;
  canvas.height = 60;
  g.font = "48px system-ui, sans-serif";
  g.fillStyle = colour;
  g.textBaseline = "middle";
  g.fillText(text, 4, 32);
  const material = new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(canvas), depthTest: false });
  const sprite = new THREE.Sprite(material);
  sprite.scale.set((height * canvas.width) / canvas.height, height, 1);
  return sprite;
}

function segments(points, colour, dashed = false) {
  const geometry = new THREE.BufferGeometry().setFromPoints(points);
  const material = dashed
    ? new THREE.LineDashedMaterial({ color: colour, dashSize: 0.08, gapSize: 0.06 })
    : new THREE.LineBasicMaterial({ color: colour });
  const lines = new THREE.LineSegments(geometry, material);
  if (dashed) lines.computeLineDistances();
  return lines;
}

// The floor grid, the arena's edges, the axes at the origin and the metre labels.
function arenaObjects(arena) {
  const [min, max] = [new THREE.Vector3(...arena.min), new THREE.Vector3(...arena.max)];
  const group = new THREE.Group();
  const minor = [], major = [];
  for (let x = Math.ceil(min.x * 2) / 2; x <= max.x + 1e-9; x += 0.5) {
    (Number.isInteger(x) ? major : minor).push(new THREE.Vector3(x, min.y, min.z), new THREE.Vector3(x, max.y, min.z));
  }
  for (let y = Math.ceil(min.y * 2) / 2; y <= max.y + 1e-9; y += 0.5) {
    (Number.isInteger(y) ? major : minor).push(new THREE.Vector3(min.x, y, min.z), new THREE.Vector3(max.x, y, min.z));
  }
  group.add(segments(minor, COLOURS.grid), segments(major, COLOURS.major));
  const size = new THREE.Vector3().subVectors(max, min);
  const box = new THREE.LineSegments(new THREE.EdgesGeometry(new THREE.BoxGeometry(size.x, size.y, size.z)),
    new THREE.LineBasicMaterial({ color: COLOURS.box }));
  box.position.addVectors(min, max).multiplyScalar(0.5);
  group.add(box);
  const origin = new THREE.Vector3(0, 0, min.z);
  [[1, 0, 0, 0xe5534b, "x"], [0, 1, 0, 0x57ab5a, "y"], [0, 0, 1, 0x539bf5, "z"]].forEach(([x, y, z, colour, name]) => {
    const end = origin.clone().add(new THREE.Vector3(x, y, z));
    group.add(segments([origin, end], colour));
    const tag = label(name, `#${colour.toString(16).padStart(6, "0")}`, 0.26);
    tag.position.copy(end).add(new THREE.Vector3(x, y, z).multiplyScalar(0.15));
    group.add(tag);
  });
  for (let x = Math.ceil(min.x); x <= max.x; x += 1) {
    const tag = label(`${x} m`);
    tag.position.set(x, min.y - 0.3, min.z);
    group.add(tag);
  }
  for (let y = Math.ceil(min.y); y <= max.y; y += 1) {
    const tag = label(`${y} m`);
    tag.position.set(max.x + 0.4, y, min.z);
    group.add(tag);
  }
  for (let z = Math.ceil(min.z) + 1; z <= max.z; z += 1) {
    const tag = label(`${z} m`);
    tag.position.set(min.x - 0.3, min.y, z);
    group.add(segments([new THREE.Vector3(min.x, min.y, z), new THREE.Vector3(min.x + 0.15, min.y, z)], COLOURS.box));
    group.add(tag);
  }
  return group;
}

// A line through points moved every message (a cable: two; a plate's outline: N + 1).
const MAX_LINE_POINTS = 9;

function movingLine(colour, dashed = false) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(new Float32Array(3 * MAX_LINE_POINTS), 3));
  const material = dashed
    ? new THREE.LineDashedMaterial({ color: colour, dashSize: 0.08, gapSize: 0.06 })
    : new THREE.LineBasicMaterial({ color: colour });
  const line = new THREE.Line(geometry, material);
  line.frustumCulled = false;
  line.place = (...points) => {
    const position = geometry.attributes.position;
    points.forEach((point, i) => position.setXYZ(i, ...point));
    geometry.setDrawRange(0, points.length);
    position.needsUpdate = true;
    if (dashed) line.computeLineDistances();
    line.visible = true;
  };
  return line;
}

// A payload that is not a bar: the polygon through its attachments, a fan of triangles
// from their centroid, moved every message.
function movingPlate(colour) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(new Float32Array(9 * MAX_LINE_POINTS), 3));
  const material = new THREE.MeshBasicMaterial({ color: colour, side: THREE.DoubleSide, transparent: true, opacity: 0.8 });
  const plate = new THREE.Mesh(geometry, material);
  plate.frustumCulled = false;
  plate.place = (corners) => {
    const centre = corners.reduce((sum, c) => sum.map((v, k) => v + c[k] / corners.length), [0, 0, 0]);
    const position = geometry.attributes.position;
    corners.forEach((corner, i) => {
      const next = corners[(i + 1) % corners.length];
      [centre, corner, next].forEach((point, k) => position.setXYZ(3 * i + k, ...point));
    });
    geometry.setDrawRange(0, 3 * corners.length);
    position.needsUpdate = true;
    plate.visible = true;
    return centre;
  };
  return plate;
}

const known = (p) => Array.isArray(p) && p.every((v) => v !== null && v !== undefined);

// The active setpoint's path: a thin tube through its points (a WebGL line is one pixel
// wide whatever it is asked), made again only when the path changes (it holds up to 2000
// points: not rebuilt 25 times a second).
const PATH_RADIUS_M = 0.02;  // half the bar's: a few pixels with the whole arena in sight

function pathTube(colour) {
  const tube = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshBasicMaterial({ color: colour }));
  tube.frustumCulled = false;
  tube.visible = false;
  let shown = "";
  tube.show = (path) => {
    const key = path ? JSON.stringify([path.waypoints, path.duration_s, path.points.length]) : "";
    tube.visible = Boolean(path);
    if (key === shown) return;
    shown = key;
    // Points held still (its start, its end) are one point: a curve has no direction there.
    const points = [];
    for (const point of path ? path.points : []) {
      const here = new THREE.Vector3(...point);
      if (!points.length || here.distanceTo(points[points.length - 1]) > 1e-3) points.push(here);
    }
    tube.geometry.dispose();
    tube.geometry = points.length > 1
      ? new THREE.TubeGeometry(new THREE.CatmullRomCurve3(points, false, "centripetal"), points.length, PATH_RADIUS_M, 6)
      : new THREE.BufferGeometry();
  };
  return tube;
}

function start() {
  const canvas = document.getElementById("view3d");
  const note = document.getElementById("view3d-note");
  let renderer;
  try {
    // The drawing buffer is kept so that what was drawn can be read back (the page's tests).
    renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  } catch (error) {
    note.textContent = `3D view unavailable: ${error.message}`;
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setClearColor(0x0d1115);
  THREE.Object3D.DEFAULT_UP.set(0, 0, 1);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(FOV_DEG, 1, 0.05, 200);
  camera.up.set(0, 0, 1);
  const view = { ...HOME, target: new THREE.Vector3(0, 0, 0.8) };
  let fitPoints = [];  // what must be in sight at zoom 1: the arena and its labels [m]

  const bar = new THREE.Mesh(new THREE.CylinderGeometry(0.04, 0.04, 1, 16), new THREE.MeshBasicMaterial({ color: COLOURS.bar }));
  const plate = movingPlate(COLOURS.bar);  // a payload of three or more attachments
  const drop = movingLine(COLOURS.box, true);  // from the payload's middle to the floor: its height
  const uavs = [], cables = [];
  const reference = { bar: movingLine(COLOURS.ref, true), cables: [], uavs: [] };
  const path = pathTube(COLOURS.path);
  scene.add(bar, plate, drop, reference.bar, path);

  // One sphere, cable and reference ghost per UAV the status lists (two until it says).
  function ensureVehicles(count) {
    while (uavs.length < count) {
      const body = new THREE.Mesh(new THREE.SphereGeometry(0.09, 20, 12), new THREE.MeshBasicMaterial({ color: COLOURS.uav }));
      const tag = label(`UAV ${uavs.length + 1}`, "#e6e9ec", 0.24);
      body.add(tag);
      tag.position.set(0, 0, 0.28);
      const ghost = new THREE.Mesh(new THREE.SphereGeometry(0.13, 10, 6),
        new THREE.MeshBasicMaterial({ color: COLOURS.ref, wireframe: true, transparent: true, opacity: 0.35 }));
      const cable = movingLine(COLOURS.cable), referenceCable = movingLine(COLOURS.ref, true);
      for (const object of [body, ghost, cable, referenceCable]) object.visible = false;
      uavs.push(body); cables.push(cable);
      reference.uavs.push(ghost); reference.cables.push(referenceCable);
      scene.add(body, cable, ghost, referenceCable);
    }
  }
  ensureVehicles(2);
  let arenaKey = "", arenaGroup = null, floorZ = 0;
  let visible = true, pending = false, renders = 0;

  // At zoom 1 the camera is as close as it can be with every one of ``fitPoints`` in the
  // field of view, whatever the turn and the canvas's shape (a bounding sphere's fit cut
  // the arena's near corners off on a wide canvas), and aimed at the middle of what they
  // span on the screen (perspective draws the near side larger). A point q from the aim,
  // with the camera at distance d behind it along ``forward``, is at depth d + q·forward;
  // it is in sight when |q·right| ≤ depth tan(horizontal/2), and likewise up.
  function placeCamera() {
    const tanV = Math.tan((FOV_DEG * Math.PI) / 360);
    const tanH = tanV * camera.aspect;
    const c = Math.cos(view.elevation);
    const forward = new THREE.Vector3(-c * Math.cos(view.azimuth), -c * Math.sin(view.azimuth), -Math.sin(view.elevation));
    const right = new THREE.Vector3().crossVectors(forward, camera.up).normalize();
    const up = new THREE.Vector3().crossVectors(right, forward);
    const aim = view.target.clone();
    const fitDistance = () => fitPoints.reduce((d, point) => {
      const q = point.clone().sub(aim);
      const depth = q.dot(forward);
      return Math.max(d, Math.abs(q.dot(right)) / tanH - depth, Math.abs(q.dot(up)) / tanV - depth);
    }, 1);
    let distance = fitDistance();
    for (let pass = 0; pass < 3; pass += 1) {
      // The points' extents on the screen, as tangents from the camera; the aim is moved
      // toward their middle (a shift δ moves them by about δ / distance), then fitted again.
      const extent = [Infinity, -Infinity, Infinity, -Infinity];
      for (const point of fitPoints) {
        const q = point.clone().sub(aim);
        const depth = distance + q.dot(forward);
        const [x, y] = [q.dot(right) / depth, q.dot(up) / depth];
        extent[0] = Math.min(extent[0], x); extent[1] = Math.max(extent[1], x);
        extent[2] = Math.min(extent[2], y); extent[3] = Math.max(extent[3], y);
      }
      aim.addScaledVector(right, ((extent[0] + extent[1]) / 2) * distance);
      aim.addScaledVector(up, ((extent[2] + extent[3]) / 2) * distance);
      distance = fitDistance();
    }
    camera.position.copy(aim).addScaledVector(forward, -distance * FIT_MARGIN * view.zoom);
    camera.lookAt(aim);
  }

  function fit() {
    const width = Math.max(1, canvas.clientWidth), height = Math.max(1, canvas.clientHeight);
    const size = renderer.getSize(new THREE.Vector2());
    if (size.x === width && size.y === height) return;  // a resize reallocates the drawing buffer
    renderer.setSize(width, height, false);
    camera.aspect = width / height;
    camera.updateProjectionMatrix();
  }

  function draw() {
    pending = false;
    lastDrawAt = performance.now();
    if (!visible) return;
    fit();
    placeCamera();
    renderer.render(scene, camera);
    renders += 1;
    canvas.dataset.renders = String(renders);
  }

  const redraw = () => { if (!pending) { pending = true; requestAnimationFrame(draw); } };
  let lastDrawAt = -Infinity, telemetryTimer = null;
  const redrawForTelemetry = () => {
    if (pending || telemetryTimer !== null) return;
    const wait = lastDrawAt + 1000 / TELEMETRY_DRAWS_HZ - performance.now();
    if (wait <= 0) redraw();
    else telemetryTimer = setTimeout(() => { telemetryTimer = null; redraw(); }, wait);
  };

  function setArena(arena) {
    const key = JSON.stringify(arena);
    if (key === arenaKey) return;
    arenaKey = key;
    if (arenaGroup) scene.remove(arenaGroup);
    arenaGroup = arenaObjects(arena);
    scene.add(arenaGroup);
    floorZ = arena.min[2];
    const [min, max] = [arena.min, arena.max];
    view.target.set((min[0] + max[0]) / 2, (min[1] + max[1]) / 2, (min[2] + max[2]) / 2);
    // The box's corners, widened by the labels (outside it by up to LABEL_M).
    fitPoints = [];
    for (const x of [min[0] - LABEL_M, max[0] + LABEL_M]) {
      for (const y of [min[1] - LABEL_M, max[1] + LABEL_M]) {
        fitPoints.push(new THREE.Vector3(x, y, min[2]), new THREE.Vector3(x, y, max[2]));
      }
    }
  }

  function place(t) {
    setArena(t.arena || { min: [-3, -3, 0], max: [3, 3, 3] });
    ensureVehicles(t.uavs.length);
    const ends = t.bar.ends;
    const barKnown = known(ends) && ends.every(known);
    bar.visible = barKnown && ends.length === 2;
    plate.visible = barKnown && ends.length > 2;
    drop.visible = barKnown;
    if (bar.visible) {
      const [a, b] = ends.map((e) => new THREE.Vector3(...e));
      const along = new THREE.Vector3().subVectors(b, a);
      bar.position.addVectors(a, b).multiplyScalar(0.5);
      bar.scale.set(1, along.length(), 1);
      bar.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), along.normalize());
      drop.place(bar.position.toArray(), [bar.position.x, bar.position.y, floorZ]);
    } else if (plate.visible) {
      const centre = plate.place(ends);
      drop.place(centre, [centre[0], centre[1], floorZ]);
    }
    t.uavs.forEach((uav, i) => {
      const shown = known(uav.position);
      uavs[i].visible = shown;
      if (shown) uavs[i].position.set(...uav.position);
      cables[i].visible = shown && barKnown;
      if (shown && barKnown) cables[i].place(uav.position, ends[i]);
      uavs[i].material.color.set(uav.connected ? COLOURS.uav : COLOURS.cable);  // grey: link lost
    });
    const r = t.reference;
    const referenceKnown = r && r.bar_ends.every(known);
    reference.bar.visible = Boolean(referenceKnown);
    reference.uavs.forEach((ghost, i) => {
      const shown = referenceKnown && known(r.uav_positions[i]);
      ghost.visible = reference.cables[i].visible = Boolean(shown);
      if (shown) {
        ghost.position.set(...r.uav_positions[i]);
        reference.cables[i].place(r.uav_positions[i], r.bar_ends[i]);
      }
    });
    // The reference payload: the bar's axis, or the closed outline of the attachments.
    if (referenceKnown) {
      const outline = r.bar_ends.length > 2 ? [...r.bar_ends, r.bar_ends[0]] : r.bar_ends;
      reference.bar.place(...outline);
    }
    path.show(t.path);
    redrawForTelemetry();
  }

  // Where a point of the arena is drawn [CSS pixels from the canvas's top left].
  function project(point) {
    fit();
    placeCamera();
    camera.updateMatrixWorld();
    const p = new THREE.Vector3(...point).project(camera);
    return [(p.x + 1) / 2 * canvas.clientWidth, (1 - p.y) / 2 * canvas.clientHeight];
  }

  let drag = null;
  canvas.addEventListener("pointerdown", (event) => { drag = [event.clientX, event.clientY]; canvas.setPointerCapture(event.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (event) => {
    if (!drag) return;
    view.azimuth -= (event.clientX - drag[0]) * 0.01;
    view.elevation = Math.min(1.5, Math.max(-0.1, view.elevation + (event.clientY - drag[1]) * 0.01));
    drag = [event.clientX, event.clientY];
    redraw();
  });
  canvas.addEventListener("wheel", (event) => {
    event.preventDefault();
    view.zoom = Math.min(5, Math.max(0.1, view.zoom * Math.exp(event.deltaY * 0.001)));
    redraw();
  }, { passive: false });
  canvas.addEventListener("dblclick", () => { Object.assign(view, HOME); redraw(); });
  new ResizeObserver(redraw).observe(canvas);
  new IntersectionObserver(([entry]) => { visible = entry.isIntersecting; if (visible) redraw(); }).observe(canvas);
  window.addEventListener("uavbar:telemetry", (event) => place(event.detail));
  // For the page's tests: where things are drawn, and what must be in sight at zoom 1.
  window.uavbarView3d = {
    project,
    fitPoints: () => fitPoints.map((p) => p.toArray()),
    webgl: renderer.capabilities.isWebGL2 ? "webgl2" : "webgl",
  };
}

start();
