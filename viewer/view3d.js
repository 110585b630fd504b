// flashtwin's 3D review of one run (DIR/view3d.html). Plain script: three.js is the global
// THREE (defined by the script before this one), the run's data is the JSON in #ft-data.
// Everything is in the casting frame {C}, in millimetres.
// URL hash options (for tests and benchmarks): #only=LAYER shows that layer alone, #hide=A,B
// hides layers, #bench orbits the camera for 5 s and records the frame rate (also logged to
// the console), #time=F puts the robot at the fraction F of the executed motion, #density=X
// draws X times the default number of points (0.25, 0.5, 1, 2, 4, 8), #go=residual|gouges
// presses that "worst" button, #pixels records the share of drawn pixels (drawn_fraction),
// #log also logs the status to the console. #ft-status (hidden) holds a JSON summary: ready,
// ready_ms, layers with their item counts, errors, fps, points_drawn, drawn_fraction (#pixels),
// measure (after a click or #go).
(function () {
  'use strict';
  const status = { ready: false, errors: [], layers: {}, fps: null };
  const statusEl = document.getElementById('ft-status');
  // #log (parsed below, before anything can fail) also writes the status to the console, for
  // browsers whose headless mode dumps no DOM (Firefox).
  const logStatus = /(^#|&)log(&|=|$)/.test(window.location.hash);
  const report = () => {
    statusEl.textContent = JSON.stringify(status);
    if (logStatus) console.log('ft-status ' + statusEl.textContent);
  };
  window.addEventListener('error', (e) => { status.errors.push(String(e.message)); report(); });
  window.addEventListener('unhandledrejection', (e) => {
    status.errors.push('unhandled rejection: ' + String(e.reason)); report();
  });
  report();

  const hash = {};
  for (const kv of window.location.hash.replace(/^#/, '').split('&')) {
    if (!kv) continue;
    const i = kv.indexOf('=');
    hash[i < 0 ? kv : kv.slice(0, i)] = i < 0 ? '1' : decodeURIComponent(kv.slice(i + 1));
  }

  const data = JSON.parse(document.getElementById('ft-data').textContent);

  // Base64 of little-endian bytes -> typed array.
  function decode(b64, Type) {
    const bin = atob(b64 || '');
    const u8 = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; ++i) u8[i] = bin.charCodeAt(i);
    return new Type(u8.buffer);
  }

  // ---- Renderer, camera, lights.
  const host = document.getElementById('ft-view');
  // No multisampling: in a software renderer (SwiftShader) it costs more than the points.
  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ antialias: false });
  } catch (e) {
    document.getElementById('ft-view').innerHTML = '<p style="padding:2em">This browser gives the ' +
      'page no WebGL context, so the 3D view cannot be drawn (' + String(e.message || e) + '). ' +
      'Enable WebGL (hardware or software rendering) and reload.</p>';
    status.errors.push('no WebGL: ' + String(e.message || e));
    report();
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  host.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0xf4f5f7);
  const camera = new THREE.PerspectiveCamera(40, 1, 0.5, 50000);
  camera.up.set(0, 0, 1);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x8090a0, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  scene.add(sun);

  // ---- Orbit / pan / zoom about a target (z up).
  const view = { target: new THREE.Vector3(), radius: 300, theta: -Math.PI / 3, phi: 0.95 };
  function placeCamera() {
    const s = Math.sin(view.phi);
    const dir = new THREE.Vector3(s * Math.cos(view.theta), s * Math.sin(view.theta), Math.cos(view.phi));
    camera.position.copy(view.target).addScaledVector(dir, view.radius);
    camera.lookAt(view.target);
    camera.near = Math.max(0.05, view.radius / 500);
    camera.far = view.radius * 100 + 5000;
    camera.updateProjectionMatrix();
    sun.position.copy(camera.position).add(new THREE.Vector3(0, 0, view.radius));
  }
  let pending = false;
  function render() { placeCamera(); renderer.render(scene, camera); }

  // Share of the view's pixels that differ from the background, read from the drawing buffer
  // right after render() (before the browser presents and clears it): #pixels checks that a
  // layer draws where a headless screenshot cannot see WebGL (Firefox).
  function drawnFraction() {
    const gl = renderer.getContext();
    const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    const px = new Uint8Array(4 * w * h);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let drawn = 0;
    for (let i = 0; i < px.length; i += 4)
      drawn += Math.abs(px[i] - 0xf4) + Math.abs(px[i + 1] - 0xf5) + Math.abs(px[i + 2] - 0xf7) > 12;
    return w * h > 0 ? drawn / (w * h) : 0;
  }
  function requestRender() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; render(); });
  }
  function resize() {
    const w = Math.max(1, host.clientWidth), h = Math.max(1, host.clientHeight);
    renderer.setSize(w, h);
    camera.aspect = w / h;
    requestRender();
  }
  window.addEventListener('resize', resize);

  let drag = null;
  renderer.domElement.addEventListener('contextmenu', (e) => e.preventDefault());
  renderer.domElement.addEventListener('pointerdown', (e) => {
    drag = { x: e.clientX, y: e.clientY, x0: e.clientX, y0: e.clientY, pan: e.button === 2 || e.shiftKey };
    renderer.domElement.setPointerCapture(e.pointerId);
  });
  renderer.domElement.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) {
      // Move the target in the view plane by what the drag covers at the target's depth.
      const k = 2 * view.radius * Math.tan((camera.fov * Math.PI) / 360) / host.clientHeight;
      const right = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 0);
      const up = new THREE.Vector3().setFromMatrixColumn(camera.matrix, 1);
      view.target.addScaledVector(right, -dx * k).addScaledVector(up, dy * k);
    } else {
      view.theta -= dx * 0.008;
      view.phi = Math.min(Math.PI - 0.01, Math.max(0.01, view.phi - dy * 0.008));
    }
    requestRender();
  });
  renderer.domElement.addEventListener('pointerup', (e) => {
    const click = drag && Math.abs(e.clientX - drag.x0) + Math.abs(e.clientY - drag.y0) < 4;
    drag = null;
    if (click) pick(e);
  });
  renderer.domElement.addEventListener('wheel', (e) => {
    e.preventDefault();
    view.radius = Math.min(20000, Math.max(1, view.radius * Math.exp(e.deltaY * 0.001)));
    requestRender();
  }, { passive: false });

  function fitTo(box) {
    if (box.isEmpty()) return;
    const size = box.getSize(new THREE.Vector3()).length();
    box.getCenter(view.target);
    view.radius = Math.max(5, 0.6 * size / Math.tan((camera.fov * Math.PI) / 360));
    requestRender();
  }

  // ---- Colours.
  function ramp(f) {  // 0..1 -> yellow, orange, red, dark purple (a heat scale)
    const stops = [[1.0, 0.95, 0.35], [0.99, 0.55, 0.15], [0.85, 0.12, 0.15], [0.35, 0.0, 0.35]];
    const x = Math.min(1, Math.max(0, f)) * (stops.length - 1);
    const i = Math.min(stops.length - 2, Math.floor(x)), t = x - i;
    return stops[i].map((a, k) => a + (stops[i + 1][k] - a) * t);
  }
  function rampDeep(f) {  // 0..1 -> light blue, blue, dark blue (gouge depth)
    const stops = [[0.65, 0.85, 1.0], [0.2, 0.45, 0.95], [0.05, 0.05, 0.45]];
    const x = Math.min(1, Math.max(0, f)) * (stops.length - 1);
    const i = Math.min(stops.length - 2, Math.floor(x)), t = x - i;
    return stops[i].map((a, k) => a + (stops[i + 1][k] - a) * t);
  }
  const palette = [0x1f77b4, 0xff7f0e, 0x2ca02c, 0xd62728, 0x9467bd, 0x8c564b, 0xe377c2, 0x17becf];
  const css = (rgb) => 'rgb(' + rgb.map((c) => Math.round(c * 255)).join(',') + ')';

  // ---- Layers.
  const layers = [];  // {key, name, object, count, swatch, pickable}
  function addLayer(key, name, object, count, swatch, pickable) {
    object.visible = true;
    scene.add(object);
    layers.push({ key, name, object, count, swatch, pickable });
    status.layers[key] = { count };
  }
  // Point layers draw a prefix of their (shuffled) points: base × the density factor.
  const pointLayers = [];  // {object, stored, base}
  function pointsObject(xyz, colors, size) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(xyz, 3));
    g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    g.computeBoundingBox();
    g.computeBoundingSphere();
    const m = new THREE.PointsMaterial({ size, sizeAttenuation: false, vertexColors: true });
    return new THREE.Points(g, m);
  }
  function lineObject(xyz, closed, color, width) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(xyz, 3));
    const m = new THREE.LineBasicMaterial({ color, linewidth: width || 1, depthTest: true });
    return closed ? new THREE.LineLoop(g, m) : new THREE.Line(g, m);
  }

  // Casting CAD (pushed back in depth a little so points and lines on its surface show).
  let cadMesh = null, cadPos = null, cadIdx = null;
  const partBox = new THREE.Box3();
  if (data.cad) {
    cadPos = decode(data.cad.xyz, Float32Array);
    cadIdx = decode(data.cad.index, Uint32Array);
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(cadPos, 3));
    g.setIndex(new THREE.BufferAttribute(cadIdx, 1));
    g.computeBoundingBox();
    g.computeBoundingSphere();
    partBox.copy(g.boundingBox);
    const m = new THREE.MeshStandardMaterial({
      color: 0xb8bcc4, metalness: 0.15, roughness: 0.7, flatShading: true,
      polygonOffset: true, polygonOffsetFactor: 1, polygonOffsetUnits: 1,
    });
    cadMesh = new THREE.Mesh(g, m);
    addLayer('cad', 'Casting CAD', cadMesh, cadIdx.length / 3, 'rgb(184,188,196)', true);
  }

  // Scan, coloured by perception's labels.
  const labelColors = [[0.05, 0.2, 0.6], [1.0, 0.35, 0.0], [0.78, 0.78, 0.78]];
  const labelNames = ['body', 'flash', 'ignored (support, outlier, outside)'];
  let scanLabels = null;
  if (data.scan) {
    const xyz = decode(data.scan.xyz, Float32Array);
    scanLabels = decode(data.scan.label, Uint8Array);
    const col = new Float32Array(xyz.length);
    for (let i = 0; i < scanLabels.length; ++i) col.set(labelColors[Math.min(2, scanLabels[i])], 3 * i);
    const pts = pointsObject(xyz, col, 2);
    pointLayers.push({ object: pts, stored: scanLabels.length, base: 12000 });
    addLayer('scan', 'Scan by label: body, flash, ignored (' + scanLabels.length + ' of ' + data.scan.total +
      ' points)', pts, scanLabels.length,
      'linear-gradient(90deg,rgb(62,124,203) 33%,rgb(255,89,0) 33% 66%,rgb(199,199,199) 66%)', true);
  }

  function polylineGroup(list, colorOf) {
    const grp = new THREE.Group();
    list.forEach((p, k) => {
      const xyz = decode(p.xyz, Float32Array);
      if (xyz.length >= 6) grp.add(lineObject(xyz, p.closed, colorOf(k)));
    });
    return grp;
  }
  if (data.roots) {
    addLayer('roots', 'True flash roots', polylineGroup(data.roots, () => 0x118811), data.roots.length,
      'rgb(17,136,17)', false);
  }
  if (data.paths) {
    addLayer('paths', 'Detected paths', polylineGroup(data.paths, (k) => palette[k % palette.length]),
      data.paths.length, 'rgb(31,119,180)', false);
  }

  // Planned tool path (TCP), coloured by the kind of move.
  const kindColors = [[0.2, 0.45, 0.95], [0.85, 0.1, 0.55], [1.0, 0.6, 0.0], [0.1, 0.75, 0.75]];
  if (data.toolpath) {
    const grp = new THREE.Group();
    let n = 0;
    for (const tp of data.toolpath) {
      const xyz = decode(tp.xyz, Float32Array), kind = decode(tp.kind, Uint8Array);
      if (kind.length < 2) continue;
      const col = new Float32Array(xyz.length);
      for (let i = 0; i < kind.length; ++i) col.set(kindColors[Math.min(3, kind[i])], 3 * i);
      const g = new THREE.BufferGeometry();
      g.setAttribute('position', new THREE.BufferAttribute(xyz, 3));
      g.setAttribute('color', new THREE.BufferAttribute(col, 3));
      grp.add(new THREE.Line(g, new THREE.LineBasicMaterial({ vertexColors: true })));
      n += kind.length;
    }
    addLayer('toolpath', 'Planned tool path (TCP)', grp, n,
      'linear-gradient(90deg,rgb(51,115,242) 33%,rgb(217,26,140) 33% 66%,rgb(26,191,191) 66%)', false);
  }

  // Residual flash and gouges: voxels coloured by height / depth [mm], with legends.
  const legends = document.getElementById('ft-legends');
  function legend(title, max, fn) {
    const stops = [0, 0.25, 0.5, 0.75, 1].map((f) => css(fn(f)) + ' ' + f * 100 + '%').join(',');
    const div = document.createElement('div');
    div.className = 'ft-legend';
    div.innerHTML = '<div>' + title + '</div><div class="ft-ramp" style="background:linear-gradient(90deg,' +
      stops + ')"></div><div class="ft-ramp-labels"><span>0</span><span>' + (max / 2).toFixed(2) +
      '</span><span>' + max.toFixed(2) + ' mm</span></div>';
    legends.appendChild(div);
  }
  const maps = {};
  function mapLayer(key, name, d, fn, size) {
    const xyz = decode(d.xyz, Float32Array), val = decode(d.value, Float32Array);
    const max = d.worst ? Math.max(d.worst.value, 1e-3) : 1e-3;
    const col = new Float32Array(xyz.length);
    for (let i = 0; i < val.length; ++i) col.set(fn(val[i] / max), 3 * i);
    const pts = pointsObject(xyz, col, size);
    pointLayers.push({ object: pts, stored: val.length, base: 5000 });
    maps[key] = { values: val, worst: d.worst, object: pts };
    addLayer(key, name + ' (' + d.total + ' voxels' + (d.worst ? ', max ' + d.worst.value.toFixed(2) + ' mm' : '') + ')',
      pts, val.length, css(fn(0.7)), true);
    if (d.worst) legend(name + ' [mm]', max, fn);
  }
  if (data.residual) mapLayer('residual', 'Residual flash height', data.residual, ramp, 3);
  if (data.gouges) mapLayer('gouges', 'Gouge depth', data.gouges, rampDeep, 2);

  // The robot along the executed motion: links between the D-H frame origins, the spindle
  // from the flange to the TCP and the burr.
  const robot = data.robot ? {
    t: decode(data.robot.t, Float32Array), force: decode(data.robot.force, Float32Array),
    path: decode(data.robot.path, Int32Array), xyz: decode(data.robot.xyz, Float32Array),
    per: data.robot.points_per_frame, toolR: data.robot.tool_radius_mm,
  } : null;
  const robotParts = [];
  if (robot && robot.t.length > 0) {
    const grp = new THREE.Group();
    const cyl = new THREE.CylinderGeometry(1, 1, 1, 20);
    // Translucent arm and spindle: the burr's contact with the part stays in sight.
    const see = { transparent: true, opacity: 0.35, depthWrite: false };
    const linkMat = new THREE.MeshStandardMaterial({ color: 0xf0a020, metalness: 0.2, roughness: 0.6, ...see });
    const toolMat = new THREE.MeshStandardMaterial({ color: 0x707880, metalness: 0.5, roughness: 0.4, ...see });
    const burrMat = new THREE.MeshStandardMaterial({ color: 0x303030, metalness: 0.6, roughness: 0.3 });
    for (let j = 0; j + 1 < robot.per; ++j) {
      const last = j + 2 === robot.per;  // flange -> TCP: the spindle
      const m = new THREE.Mesh(cyl, last ? toolMat : linkMat);
      m.userData.r = last ? 28 : (j < 3 ? 60 : 42);
      grp.add(m);
      robotParts.push(m);
    }
    const joint = new THREE.SphereGeometry(1, 20, 12);
    for (let j = 0; j + 1 < robot.per; ++j) {
      const s = new THREE.Mesh(joint, linkMat);
      s.scale.setScalar(j < 3 ? 64 : 46);
      grp.add(s);
      robotParts.push(s);
    }
    const burr = new THREE.Mesh(new THREE.SphereGeometry(1, 24, 16), burrMat);
    burr.scale.setScalar(robot.toolR);
    grp.add(burr);
    robotParts.push(burr);
    addLayer('robot', 'Robot (executed motion)', grp, robot.t.length, 'rgb(240,160,32)', false);
  }
  const yAxis = new THREE.Vector3(0, 1, 0);
  function setRobotFrame(f) {
    if (!robot) return;
    const P = (j) => new THREE.Vector3(robot.xyz[3 * (f * robot.per + j)], robot.xyz[3 * (f * robot.per + j) + 1],
      robot.xyz[3 * (f * robot.per + j) + 2]);
    const n = robot.per - 1;
    for (let j = 0; j < n; ++j) {
      const a = P(j), b = P(j + 1), m = robotParts[j];
      const d = b.clone().sub(a), len = d.length();
      m.visible = len > 1e-3;
      if (!m.visible) continue;
      m.position.copy(a).add(b).multiplyScalar(0.5);
      m.quaternion.setFromUnitVectors(yAxis, d.normalize());
      m.scale.set(m.userData.r, len, m.userData.r);
    }
    for (let j = 0; j < n; ++j) robotParts[n + j].position.copy(P(j));
    robotParts[2 * n].position.copy(P(n));
    const label = document.getElementById('ft-time-label');
    label.textContent = 't ' + robot.t[f].toFixed(2) + ' s \u00b7 path ' + robot.path[f] +
      ' \u00b7 normal force ' + robot.force[f].toFixed(1) + ' N';
    requestRender();
  }
  const slider = document.getElementById('ft-time');
  if (robot && robot.t.length > 0) {
    slider.max = String(robot.t.length - 1);
    slider.addEventListener('input', () => setRobotFrame(Number(slider.value)));
    const f0 = hash.time ? Math.round(Number(hash.time) * (robot.t.length - 1)) : 0;
    slider.value = String(Math.min(robot.t.length - 1, Math.max(0, f0)));
    setRobotFrame(Number(slider.value));
  } else {
    slider.disabled = true;
    document.getElementById('ft-time-label').textContent = 'no executed motion in this run';
  }

  // ---- Layer switches.
  const layersDiv = document.getElementById('ft-layers');
  for (const L of layers) {
    const lab = document.createElement('label');
    const cb = document.createElement('input');
    cb.type = 'checkbox';
    cb.checked = true;
    cb.id = 'ft-layer-' + L.key;
    cb.addEventListener('change', () => { L.object.visible = cb.checked; requestRender(); });
    L.checkbox = cb;
    lab.appendChild(cb);
    const sw = document.createElement('span');
    sw.className = 'ft-swatch';
    sw.style.background = L.swatch;
    lab.appendChild(sw);
    lab.appendChild(document.createTextNode(L.name));
    layersDiv.appendChild(lab);
  }
  function showLayer(key, on) {
    for (const L of layers) if (L.key === key) { L.object.visible = on; L.checkbox.checked = on; }
  }

  // ---- Point density (the default keeps orbiting fluid in a software renderer).
  const factors = [0.25, 0.5, 1, 2, 4, 8];
  const densityDiv = document.createElement('div');
  densityDiv.innerHTML = '<label>Point density <input type="range" id="ft-density" min="0" max="' +
    (factors.length - 1) + '" step="1"></label> <span id="ft-density-label"></span>';
  layersDiv.appendChild(densityDiv);
  const densityInput = document.getElementById('ft-density');
  function setDensity(k) {
    const f = factors[k];
    let drawn = 0;
    for (const P of pointLayers) {
      const n = Math.min(P.stored, Math.round(P.base * f));
      P.object.geometry.setDrawRange(0, n);
      drawn += n;
    }
    status.points_drawn = drawn;
    document.getElementById('ft-density-label').textContent = '\u00d7' + f + ' (' + drawn + ' points)';
    requestRender();
  }
  const k0 = hash.density ? factors.indexOf(Number(hash.density)) : 2;
  densityInput.value = String(k0 >= 0 ? k0 : 2);
  densityInput.addEventListener('input', () => setDensity(Number(densityInput.value)));
  setDensity(Number(densityInput.value));

  // ---- Measuring click: the nearest visible pickable hit, its {C} coordinates and its
  // distance to the CAD (closest point over the CAD's triangles).
  const marker = new THREE.Mesh(new THREE.SphereGeometry(1, 16, 12),
    new THREE.MeshBasicMaterial({ color: 0x00cc44, depthTest: false }));
  marker.renderOrder = 10;
  marker.visible = false;
  scene.add(marker);
  const raycaster = new THREE.Raycaster();
  function closestOnTriangle(p, a, b, c) {  // Ericson, Real-Time Collision Detection 5.1.5
    const ab = b.clone().sub(a), ac = c.clone().sub(a), ap = p.clone().sub(a);
    const d1 = ab.dot(ap), d2 = ac.dot(ap);
    if (d1 <= 0 && d2 <= 0) return a.clone();
    const bp = p.clone().sub(b), d3 = ab.dot(bp), d4 = ac.dot(bp);
    if (d3 >= 0 && d4 <= d3) return b.clone();
    const vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return a.clone().addScaledVector(ab, d1 / (d1 - d3));
    const cp = p.clone().sub(c), d5 = ab.dot(cp), d6 = ac.dot(cp);
    if (d6 >= 0 && d5 <= d6) return c.clone();
    const vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return a.clone().addScaledVector(ac, d2 / (d2 - d6));
    const va = d3 * d6 - d5 * d4;
    if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0)
      return b.clone().addScaledVector(c.clone().sub(b), (d4 - d3) / ((d4 - d3) + (d5 - d6)));
    const den = 1 / (va + vb + vc);
    return a.clone().addScaledVector(ab, vb * den).addScaledVector(ac, vc * den);
  }
  function distanceToCad(p) {
    if (!cadIdx) return NaN;
    let best = Infinity;
    const a = new THREE.Vector3(), b = new THREE.Vector3(), c = new THREE.Vector3();
    for (let t = 0; t < cadIdx.length; t += 3) {
      a.fromArray(cadPos, 3 * cadIdx[t]); b.fromArray(cadPos, 3 * cadIdx[t + 1]); c.fromArray(cadPos, 3 * cadIdx[t + 2]);
      best = Math.min(best, closestOnTriangle(p, a, b, c).distanceToSquared(p));
    }
    return Math.sqrt(best);
  }
  function describe(key, index) {
    if (key === 'scan' && scanLabels) return 'scan point, label ' + labelNames[Math.min(2, scanLabels[index])];
    if (maps[key]) return (key === 'residual' ? 'residual flash, height ' : 'gouge, depth ') +
      maps[key].values[index].toFixed(3) + ' mm';
    return 'casting surface';
  }
  function showMeasure(p, what) {
    const d = distanceToCad(p);
    marker.position.copy(p);
    marker.scale.setScalar(Math.max(0.3, view.radius / 300));
    marker.visible = true;
    document.getElementById('ft-measure').textContent =
      what + '\nx ' + p.x.toFixed(3) + '\ny ' + p.y.toFixed(3) + '\nz ' + p.z.toFixed(3) +
      ' mm\ndistance to CAD ' + (isNaN(d) ? 'n/a' : d.toFixed(3) + ' mm');
    status.measure = { xyz: [p.x, p.y, p.z], distance_to_cad: d, what };
    report();
    requestRender();
  }
  function pick(e) {
    const r = renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(ndc, camera);
    raycaster.params.Points.threshold = Math.max(0.05, view.radius / 400);
    let best = null;
    for (const L of layers) {
      if (!L.pickable || !L.object.visible) continue;
      for (const hit of raycaster.intersectObject(L.object, true)) {
        if (!best || hit.distance < best.hit.distance) best = { hit, key: L.key };
        break;
      }
    }
    if (!best) return;
    const p = best.hit.index !== undefined && best.key !== 'cad'
      ? new THREE.Vector3().fromBufferAttribute(best.hit.object.geometry.attributes.position, best.hit.index)
      : best.hit.point.clone();
    showMeasure(p, describe(best.key, best.hit.index));
  }

  // ---- Buttons.
  document.getElementById('ft-fit').addEventListener('click', () => fitTo(partBox));
  function goWorst(key, label) {
    const m = maps[key];
    const btn = document.getElementById(key === 'residual' ? 'ft-worst-res' : 'ft-worst-gouge');
    if (!m || !m.worst) { btn.disabled = true; btn.title = 'no ' + label + ' in this run'; return; }
    btn.addEventListener('click', () => {
      showLayer(key, true);
      view.target.fromArray(m.worst.xyz);
      view.radius = 40;
      showMeasure(new THREE.Vector3().fromArray(m.worst.xyz), describe(key, indexOfWorst(m)));
    });
  }
  function indexOfWorst(m) {
    let k = 0;
    for (let i = 1; i < m.values.length; ++i) if (m.values[i] > m.values[k]) k = i;
    return k;
  }
  goWorst('residual', 'residual flash');
  goWorst('gouges', 'gouge');

  // ---- Title, verdict.
  const meta = data.meta || {};
  document.getElementById('ft-title').textContent =
    'flashtwin 3D view: ' + (meta.title || meta.scenario + ', seed ' + meta.seed);
  const vd = document.getElementById('ft-verdict');
  vd.textContent = (meta.exit_code === 0 ? 'exit 0: ' : 'exit ' + meta.exit_code + ': ') + (meta.verdict || '');
  vd.className = meta.exit_code === 0 ? 'ok' : 'bad';

  // ---- Start: #only=LAYER shows that layer alone (fitted to it); #bench measures fps.
  resize();
  fitTo(partBox);
  if (hash.only) {
    for (const L of layers) showLayer(L.key, L.key === hash.only);
    const L = layers.find((x) => x.key === hash.only);
    if (!L) status.errors.push('no layer ' + hash.only);
    else if (hash.only === 'robot') fitTo(new THREE.Box3().setFromObject(L.object));
  }
  if (hash.hide) for (const k of hash.hide.split(',')) showLayer(k, false);
  // #go=residual|gouges presses that "worst" button (tests read the measurement in #ft-status).
  if (hash.go) document.getElementById(hash.go === 'residual' ? 'ft-worst-res' : 'ft-worst-gouge').click();
  render();
  if (hash.pixels) status.drawn_fraction = drawnFraction();
  status.ready = true;
  status.ready_ms = Math.round(performance.now());  // from navigation start
  report();
  console.log('ft-ready ms=' + status.ready_ms);
  if (hash.bench) {
    let frames = 0;
    const t0 = performance.now(), theta0 = view.theta;
    const step = (now) => {
      const s = (now - t0) / 1000;
      view.theta = theta0 + s * 0.8;
      render();
      ++frames;
      if (s < 5) requestAnimationFrame(step);
      else {
        status.fps = frames / s;
        report();
        console.log('ft-bench fps=' + status.fps.toFixed(1) + ' frames=' + frames + ' seconds=' + s.toFixed(2) +
          ' size=' + host.clientWidth + 'x' + host.clientHeight);
      }
    };
    requestAnimationFrame(step);
  }
})();
