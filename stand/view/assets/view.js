// The operator page of the ADCS stand: panorama, attitude, ground track, time plots and events, drawn with the
// browser's Canvas 2D API. Live runs push samples over a websocket; replays load once and play from the slider.
// Conventions (stand.view.state): q scalar-first Hamilton, dcm(q_BN) maps N components to B; the panorama is
// seen from inside the sphere: longitude atan2(y, x) grows to the left, latitude asin(z) up.
"use strict";

(function () {
  const D2R = Math.PI / 180, R2D = 180 / Math.PI;
  const R_EARTH = 6378137.0;
  const FRAME_NAMES = { B: "body", N: "GCRS", O: "LVLH", E: "ITRS", S: "ESD" };
  const EULER_SEQS = ["321", "312", "123", "132", "213", "231", "313", "323", "121", "131", "212", "232"];
  const COLORS = { sun: "rgb(255,200,0)", moon: "rgb(190,196,210)", valid: "rgb(60,220,90)",
    sunFlag: "rgb(255,60,60)", moonFlag: "rgb(255,150,40)", earthFlag: "rgb(80,160,255)", rate: "rgb(200,110,255)",
    nosol: "rgb(140,140,140)", axes: ["rgb(255,85,85)", "rgb(85,230,120)", "rgb(90,150,255)"] };
  // Bits of NAME.flags (the tracker ICD's flags byte; bit 0 is "valid") that say why a solution is not valid.
  const FLAG_BITS = [[2, "Sun", COLORS.sunFlag], [4, "Moon", COLORS.moonFlag], [8, "Earth", COLORS.earthFlag],
    [16, "rate", COLORS.rate]];
  // Colour keys a kind may name for an invalid sample (stand/view/export.py's COLORS).
  const STATE_COLORS = { acquiring: "rgb(230,200,60)", sun_flag: COLORS.sunFlag, moon_flag: COLORS.moonFlag,
    earth_flag: COLORS.earthFlag, rate: COLORS.rate, none: COLORS.nosol, valid: COLORS.valid };

  // ------------------------------------------------------------------------------------------ small linear algebra
  function dcm(q) {
    const [w, x, y, z] = q;
    return [[1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
      [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
      [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]];
  }
  const mv = (M, v) => [M[0][0] * v[0] + M[0][1] * v[1] + M[0][2] * v[2],
    M[1][0] * v[0] + M[1][1] * v[1] + M[1][2] * v[2], M[2][0] * v[0] + M[2][1] * v[1] + M[2][2] * v[2]];
  const mtv = (M, v) => [M[0][0] * v[0] + M[1][0] * v[1] + M[2][0] * v[2],
    M[0][1] * v[0] + M[1][1] * v[1] + M[2][1] * v[2], M[0][2] * v[0] + M[1][2] * v[1] + M[2][2] * v[2]];
  const mm = (A, B) => A.map((r) => [0, 1, 2].map((j) => r[0] * B[0][j] + r[1] * B[1][j] + r[2] * B[2][j]));
  const mT = (A) => [0, 1, 2].map((i) => [A[0][i], A[1][i], A[2][i]]);
  const I3 = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => Math.hypot(a[0], a[1], a[2]);
  const unit = (a) => { const n = norm(a); return [a[0] / n, a[1] / n, a[2] / n]; };
  const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];

  function quatFromDcm(C) {  // Shepperd: the largest of the four candidates, w >= 0
    const tr = C[0][0] + C[1][1] + C[2][2];
    const c = [tr, C[0][0], C[1][1], C[2][2]];
    let i = c.indexOf(Math.max(...c)), q;
    if (i === 0) { const w = 0.5 * Math.sqrt(1 + tr); q = [w, (C[1][2] - C[2][1]) / (4 * w), (C[2][0] - C[0][2]) / (4 * w), (C[0][1] - C[1][0]) / (4 * w)]; }
    else if (i === 1) { const x = 0.5 * Math.sqrt(1 + 2 * C[0][0] - tr); q = [(C[1][2] - C[2][1]) / (4 * x), x, (C[0][1] + C[1][0]) / (4 * x), (C[2][0] + C[0][2]) / (4 * x)]; }
    else if (i === 2) { const y = 0.5 * Math.sqrt(1 + 2 * C[1][1] - tr); q = [(C[2][0] - C[0][2]) / (4 * y), (C[0][1] + C[1][0]) / (4 * y), y, (C[1][2] + C[2][1]) / (4 * y)]; }
    else { const z = 0.5 * Math.sqrt(1 + 2 * C[2][2] - tr); q = [(C[0][1] - C[1][0]) / (4 * z), (C[2][0] + C[0][2]) / (4 * z), (C[1][2] + C[2][1]) / (4 * z), z]; }
    if (q[0] < 0) q = q.map((x) => -x);
    const n = Math.hypot(...q);
    return q.map((x) => x / n);
  }

  // Euler angles of a DCM for a sequence "ijk": dcm = M_k(a3) M_j(a2) M_i(a1) (sim.rotations.euler_from_quat).
  function eulerFromDcm(C, seq) {
    const i = +seq[0] - 1, j = +seq[1] - 1, k = +seq[2] - 1, s = ((j - i + 3) % 3) === 1 ? 1 : -1;
    let a1, a2, a3;
    if (i !== k) {
      const sin2 = Math.max(-1, Math.min(1, s * C[k][i])), cos2 = Math.hypot(C[k][j], C[k][k]);
      a2 = Math.atan2(sin2, cos2); a1 = Math.atan2(-s * C[k][j], C[k][k]); a3 = Math.atan2(-s * C[j][i], C[i][i]);
      if (cos2 < 1e-9) { const m = 3 - i - j; a1 = Math.atan2(s * C[j][m], C[j][j]); a3 = 0; }
    } else {
      const m = 3 - i - j, sin2 = Math.hypot(C[i][j], C[i][m]);
      a2 = Math.atan2(sin2, Math.max(-1, Math.min(1, C[i][i])));
      a1 = Math.atan2(C[i][j], -s * C[i][m]); a3 = Math.atan2(C[j][i], s * C[m][i]);
      if (sin2 < 1e-9) { a1 = Math.atan2(s * C[j][m], C[j][j]); a3 = 0; }
    }
    return [a1, a2, a3];
  }

  function lvlh(r, v) {  // rows: x, y, z of LVLH in N (z nadir, y negative orbit normal)
    const z = scale(unit(r), -1), y = scale(unit(cross(r, v)), -1);
    return [cross(y, z), y, z];
  }
  function esdOfItrs(rE) {
    const down = scale(unit(rE), -1), east = unit(cross([0, 0, 1], scale(down, -1)));
    return [east, cross(down, east), down];
  }

  // ------------------------------------------------------------------------------------------ projection
  const proj = {
    equirectangular: {
      fwd(u, W, H) { const lon = Math.atan2(u[1], u[0]), lat = Math.asin(Math.max(-1, Math.min(1, u[2])));
        return [W / 2 - lon / (2 * Math.PI) * W, H / 2 - lat / Math.PI * H]; },
      inv(x, y, W, H) { const lon = (W / 2 - x) / W * 2 * Math.PI, lat = (H / 2 - y) / H * Math.PI;
        if (Math.abs(lat) > Math.PI / 2 || Math.abs(lon) > Math.PI) return null;
        return [Math.cos(lat) * Math.cos(lon), Math.cos(lat) * Math.sin(lon), Math.sin(lat)]; },
    },
    hammer: {
      fwd(u, W, H) { const lon = Math.atan2(u[1], u[0]), lat = Math.asin(Math.max(-1, Math.min(1, u[2])));
        const d = Math.sqrt(1 + Math.cos(lat) * Math.cos(lon / 2));
        const hx = 2 * Math.SQRT2 * Math.cos(lat) * Math.sin(lon / 2) / d, hy = Math.SQRT2 * Math.sin(lat) / d;
        return [W / 2 - hx / (2 * Math.SQRT2) * W / 2, H / 2 - hy / Math.SQRT2 * H / 2]; },
      inv(x, y, W, H) {
        const hx = (W / 2 - x) / (W / 2) * 2 * Math.SQRT2, hy = (H / 2 - y) / (H / 2) * Math.SQRT2;
        if ((hx * hx) / 8 + (hy * hy) / 2 > 1) return null;
        const z = Math.sqrt(1 - (hx / 4) ** 2 - (hy / 2) ** 2);
        const lon = 2 * Math.atan2(z * hx, 2 * (2 * z * z - 1)), lat = Math.asin(Math.max(-1, Math.min(1, z * hy)));
        return [Math.cos(lat) * Math.cos(lon), Math.cos(lat) * Math.sin(lon), Math.sin(lat)]; },
    },
  };

  // A perspective from the centre of the sphere (stereographic, so circles stay circles): the look axes are set
  // before every drawing (S.lookAxes: right, up, forward in the panorama's frame), the width of view in S.lookFov.
  proj.inside = {
    scale(W) { return (W / 2) / (2 * Math.tan(S.lookFov * D2R / 4)); },
    fwd(u, W, H) {
      const [rt, up, fw] = S.lookAxes, f = dot(u, fw), k = 2 / Math.max(1 + f, 1e-6), sc = this.scale(W);
      return [W / 2 + k * dot(u, rt) * sc, H / 2 - k * dot(u, up) * sc];
    },
    inv(x, y, W, H) {
      const sc = this.scale(W), X = (x - W / 2) / sc, Y = (H / 2 - y) / sc, r2 = X * X + Y * Y;
      const f = (4 - r2) / (4 + r2), g = (1 + f) / 2, [rt, up, fw] = S.lookAxes;
      return [0, 1, 2].map((j) => f * fw[j] + g * (X * rt[j] + Y * up[j]));
    },
  };

  function lookAxes(i, M) {  // the axes of the inside view at sample i, in the panorama's frame
    const st = S.store, target = $("look-at").value, C_BN = dcm(st.get("q_BN", i)), r = st.get("r_BN_N", i);
    let fwN, upN = null;
    if (target === "nadir") fwN = scale(r, -1 / norm(r));
    else if (target === "zenith") fwN = unit(r);
    else if (target === "velocity") fwN = unit(st.get("v_BN_N", i));
    else if (target === "sun") fwN = st.get("sun_N", i);
    else if (target.startsWith("axis:")) { const [a, sgn] = [+target[5], target[6] === "-" ? -1 : 1]; fwN = scale(C_BN[a], sgn); }
    else {  // a device: its boresight, with its image axes (x right, y down) as the view's
      const dev = S.meta.devices.find((d) => d.name === target.slice(4)), toN = (v) => mtv(C_BN, mtv(dcm(dev.q_SB), v));
      fwN = toN(dev.fovs[0].axis_S);
      if (dev.fovs[0].shape === "rect") upN = scale(toN([0, 1, 0]), -1);
    }
    const fw0 = mv(M, fwN);
    let up0;
    if (upN) up0 = mv(M, upN);
    else { const ref = Math.abs(fw0[2]) > 0.98 ? [1, 0, 0] : [0, 0, 1]; up0 = unit(cross(cross(fw0, ref), fw0)); }
    const rt0 = cross(fw0, up0);
    // the drag offsets: yaw about the view's up, then pitch about its right
    const yaw = S.lookYaw * D2R, pitch = S.lookPitch * D2R;
    const fwY = [0, 1, 2].map((j) => Math.cos(yaw) * fw0[j] + Math.sin(yaw) * rt0[j]);
    const rt = [0, 1, 2].map((j) => Math.cos(yaw) * rt0[j] - Math.sin(yaw) * fw0[j]);
    const fw = [0, 1, 2].map((j) => Math.cos(pitch) * fwY[j] + Math.sin(pitch) * up0[j]);
    const up = cross(rt, fw);
    S.lookAxes = [rt, up, fw];
  }

  // ------------------------------------------------------------------------------------------ the sample store
  class Store {
    constructor() { this.n = 0; this.cols = {}; }
    static decode(enc) {
      const bin = atob(enc.data), buf = new ArrayBuffer(bin.length), u8 = new Uint8Array(buf);
      for (let i = 0; i < bin.length; i++) u8[i] = bin.charCodeAt(i);
      return { w: enc.shape[1], n: enc.shape[0], data: enc.dtype === "f8" ? new Float64Array(buf) : new Float32Array(buf) };
    }
    append(encoded) {
      const cols = Object.fromEntries(Object.entries(encoded).map(([k, v]) => [k, Store.decode(v)]));
      const add = cols.t_s ? cols.t_s.n : 0;
      if (!add) return 0;
      for (const [k, c] of Object.entries(cols)) {
        let have = this.cols[k];
        if (!have) { have = this.cols[k] = { w: c.w, data: new Float64Array(Math.max(1024, 2 * add) * c.w).fill(NaN) }; }
        const need = (this.n + add) * c.w;
        if (need > have.data.length) {
          const grown = new Float64Array(Math.max(need, 2 * have.data.length)).fill(NaN);
          grown.set(have.data.subarray(0, this.n * c.w)); have.data = grown;
        }
        have.data.set(c.data, this.n * c.w);
      }
      this.n += add;
      return add;
    }
    has(k) { return k in this.cols; }
    get(k, i) { const c = this.cols[k]; if (!c) return null; return c.w === 1 ? c.data[i] : Array.from(c.data.subarray(i * c.w, (i + 1) * c.w)); }
    t(i) { return this.cols.t_s.data[i]; }
    index(t) {  // last sample at or before t
      let lo = 0, hi = this.n - 1;
      if (hi < 0) return -1;
      if (t <= this.t(0)) return 0;
      while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (this.t(mid) <= t + 1e-9) lo = mid; else hi = mid - 1; }
      return lo;
    }
  }

  // ------------------------------------------------------------------------------------------ state
  const $ = (id) => document.getElementById(id);
  const S = {
    meta: null, store: new Store(), events: [], stars: null, land: null, t: 0, i: -1, playing: false, follow: true,
    live: false, status: "", stats: { draws: 0, firstDrawMs: null, lastDrawMs: null, pushes: 0, pushTimes: [] },
    starCache: null, modeNames: new Map(), overlay: [], faults: [], faultMarks: [], faultTypes: [], faultAnswers: [], eventsSeen: -1, frames: {},
  };
  window.standView = S;

  function frameOf(i, F) {  // dcm_FN at sample i
    if (F === "N") return I3;
    if (F === "B") return dcm(S.store.get("q_BN", i));
    if (F === "E") return dcm(S.store.get("q_EN", i));
    if (F === "O") return lvlh(S.store.get("r_BN_N", i), S.store.get("v_BN_N", i));
    if (F === "S") { const CEN = dcm(S.store.get("q_EN", i)); return mm(esdOfItrs(mv(CEN, S.store.get("r_BN_N", i))), CEN); }
    return I3;
  }

  // device state at sample i: {color, label, valid}
  // What the device's kind declares (view.json: state = {missing, flags, invalid: [colour key, text]}).
  function deviceState(dev, i) {
    const st = S.store, n = dev.name, decl = dev.state;
    if (!decl) return { color: COLORS.nosol, label: "", valid: null };
    const v = st.get(n + ".valid", i);
    if (v === null || Number.isNaN(v)) return { color: COLORS.nosol, label: decl.missing, valid: null };
    if (v >= 0.5) return { color: COLORS.valid, label: "valid", valid: true };
    const [key, text] = decl.invalid, color = STATE_COLORS[key] || COLORS.nosol;
    if (!decl.flags) return { color, label: text, valid: false };
    const f = st.get(n + ".flags", i), hit = FLAG_BITS.filter(([b]) => (f & b) !== 0);
    if (hit.length) return { color: hit[0][2], label: "invalid: " + hit.map((h) => h[1]).join(", "), valid: false, flags: f };
    return { color, label: text, valid: false, flags: f };
  }

  // ------------------------------------------------------------------------------------------ panorama
  const pano = { canvas: null, ctx: null, earth: null, earthCtx: null };

  function polyline(ctx, pts, W) {  // break where the projection wraps
    let pen = false, prev = null;
    ctx.beginPath();
    for (const p of pts) {
      if (!p || Math.abs(p[0]) > 20 * W || Math.abs(p[1]) > 20 * W) { pen = false; prev = null; continue; }
      if (prev && Math.hypot(p[0] - prev[0], p[1] - prev[1]) > W * 0.25) pen = false;
      if (pen) ctx.lineTo(p[0], p[1]); else ctx.moveTo(p[0], p[1]);
      pen = true; prev = p;
    }
    ctx.stroke();
  }

  function coneBoundary(axis, halfRad, n = 96) {
    const a = unit(axis), ref = Math.abs(a[2]) < 0.9 ? [0, 0, 1] : [1, 0, 0];
    const e1 = unit(cross(a, ref)), e2 = cross(a, e1), out = [];
    for (let k = 0; k <= n; k++) {
      const phi = 2 * Math.PI * k / n, c = Math.cos(halfRad), s = Math.sin(halfRad);
      out.push([0, 1, 2].map((j) => c * a[j] + s * (Math.cos(phi) * e1[j] + Math.sin(phi) * e2[j])));
    }
    return out;
  }

  function rectBoundary(fovDeg, n = 24) {  // in the sensor frame, boresight +z, x right
    const tx = Math.tan(fovDeg[0] * D2R / 2), ty = Math.tan(fovDeg[1] * D2R / 2), out = [];
    const corners = [[-tx, -ty], [tx, -ty], [tx, ty], [-tx, ty], [-tx, -ty]];
    for (let c = 0; c < 4; c++) {
      for (let k = 0; k < n; k++) {
        const f = k / n, x = corners[c][0] + f * (corners[c + 1][0] - corners[c][0]), y = corners[c][1] + f * (corners[c + 1][1] - corners[c][1]);
        out.push(unit([x, y, 1]));
      }
    }
    out.push(out[0]);
    return out;
  }

  function drawPanorama() {
    const i = S.i, st = S.store, cv = pano.canvas, ctx = pano.ctx, W = cv.width, H = cv.height;
    const P = proj[$("pano-proj").value], F = $("pano-frame").value;
    ctx.fillStyle = "#03050a"; ctx.fillRect(0, 0, W, H);
    if (P === proj.hammer) { ctx.fillStyle = "#070b14"; ctx.beginPath(); ctx.ellipse(W / 2, H / 2, W / 2, H / 2, 0, 0, 2 * Math.PI); ctx.fill(); }
    S.overlay = [];
    if (i < 0) return;
    const M = frameOf(i, F);  // dcm_FN
    if (P === proj.inside) lookAxes(i, M);
    $("look").hidden = P !== proj.inside;
    const toF = (uN) => mv(M, uN), at = (uN) => P.fwd(toF(uN), W, H);
    const C_BN = dcm(st.get("q_BN", i)), r = st.get("r_BN_N", i), rn = norm(r);
    const sunN = st.get("sun_N", i), moonN = st.get("moon_N", i);
    // grid of the panorama's frame
    ctx.strokeStyle = "rgba(120,140,170,0.18)"; ctx.lineWidth = 1;
    for (let lat = -60; lat <= 60; lat += 30) {
      const pts = []; for (let lon = -180; lon <= 180; lon += 3) pts.push(P.fwd([Math.cos(lat * D2R) * Math.cos(lon * D2R), Math.cos(lat * D2R) * Math.sin(lon * D2R), Math.sin(lat * D2R)], W, H));
      polyline(ctx, pts, W);
    }
    for (let lon = -150; lon <= 180; lon += 30) {
      const pts = []; for (let lat = -90; lat <= 90; lat += 3) pts.push(P.fwd([Math.cos(lat * D2R) * Math.cos(lon * D2R), Math.cos(lat * D2R) * Math.sin(lon * D2R), Math.sin(lat * D2R)], W, H));
      polyline(ctx, pts, W);
    }
    // stars
    drawStars(ctx, M, P, W, H);
    // the Earth: per pixel of a half-size raster, day and night by the Sun
    drawEarth(ctx, M, P, W, H, r, sunN, i);
    // Sun and Moon
    const trueSize = $("true-size").checked, pxPerRad = W / (2 * Math.PI);
    const bodies = [["sun", sunN, st.get("sun_radius_rad", i), COLORS.sun, 9], ["moon", moonN, st.get("moon_radius_rad", i), COLORS.moon, 7]];
    for (const [name, u, rad, col, sym] of bodies) {
      if (!u) continue;
      const p = at(u), hidden = Math.acos(Math.max(-1, Math.min(1, dot(u, scale(r, -1 / rn))))) < Math.asin(Math.min(1, R_EARTH / rn));
      ctx.fillStyle = col; ctx.strokeStyle = col;
      const rr = trueSize ? Math.max(1.5, rad * pxPerRad) : sym;
      ctx.beginPath(); ctx.arc(p[0], p[1], rr, 0, 2 * Math.PI);
      if (hidden) { ctx.lineWidth = 1.5; ctx.stroke(); } else ctx.fill();
      if (!trueSize && name === "sun") {
        ctx.lineWidth = 2; ctx.beginPath();
        for (let k = 0; k < 8; k++) { const a = k * Math.PI / 4; ctx.moveTo(p[0] + Math.cos(a) * (rr + 3), p[1] + Math.sin(a) * (rr + 3)); ctx.lineTo(p[0] + Math.cos(a) * (rr + 7), p[1] + Math.sin(a) * (rr + 7)); }
        ctx.stroke();
      }
      label(ctx, name === "sun" ? "Sun" : "Moon", p[0] + rr + 9, p[1] - 4, col);
      S.overlay.push({ name, x: p[0], y: p[1], hidden });
    }
    // velocity, nadir, field
    const v = st.get("v_BN_N", i);
    const marks = [["+v", unit(v), "rgb(255,255,255)"], ["-v", scale(unit(v), -1), "rgb(160,160,160)"], ["nadir", scale(r, -1 / rn), "rgb(120,200,255)"]];
    const b = st.has("b_true_B") ? st.get("b_true_B", i) : null;
    if (b && norm(b) > 0) marks.push(["B", unit(mtv(C_BN, b)), "rgb(230,120,255)"]);
    ctx.lineWidth = 1.5;
    for (const [name, u, col] of marks) {
      const p = at(u); ctx.strokeStyle = col;
      ctx.beginPath(); ctx.moveTo(p[0] - 6, p[1]); ctx.lineTo(p[0] + 6, p[1]); ctx.moveTo(p[0], p[1] - 6); ctx.lineTo(p[0], p[1] + 6); ctx.stroke();
      ctx.beginPath(); ctx.arc(p[0], p[1], 4, 0, 2 * Math.PI); ctx.stroke();
      label(ctx, name, p[0] + 7, p[1] + 13, col);
      S.overlay.push({ name, x: p[0], y: p[1] });
    }
    // body axes
    for (let a = 0; a < 3; a++) {
      for (const sgn of [1, -1]) {
        const p = at(scale(C_BN[a], sgn)), col = COLORS.axes[a];
        ctx.fillStyle = col; ctx.strokeStyle = col; ctx.lineWidth = 2;
        ctx.beginPath(); ctx.rect(p[0] - 4, p[1] - 4, 8, 8);
        if (sgn > 0) ctx.fill(); else ctx.stroke();
        label(ctx, (sgn > 0 ? "+" : "-") + "XYZ"[a], p[0] + 7, p[1] - 6, col);
        S.overlay.push({ name: (sgn > 0 ? "+" : "-") + "XYZ"[a], x: p[0], y: p[1] });
      }
    }
    // fields of view
    for (const dev of S.meta.devices) {
      if (!dev.fovs.length) continue;
      const ds = deviceState(dev, i), C_SB = dcm(dev.q_SB);
      const toN = (uS) => mtv(C_BN, mtv(C_SB, uS));
      for (const fov of dev.fovs) {
        if (fov.head && !$("show-heads").checked) continue;
        let col = ds.color;
        if (fov.head) {  // a coarse head is lit when its current is positive
          const cur = st.get(dev.name + ".currents", i), k = dev.fovs.indexOf(fov);
          col = cur && cur[k] > 1e-6 ? "rgba(255,210,80,0.8)" : "rgba(130,130,130,0.6)";
        }
        const boundary = fov.shape === "rect" ? rectBoundary(fov.fov_deg) : coneBoundary(fov.axis_S, fov.half_deg * D2R);
        ctx.strokeStyle = col; ctx.lineWidth = fov.head ? 1 : 2.5; ctx.setLineDash(fov.head ? [4, 4] : []);
        polyline(ctx, boundary.map((u) => at(toN(u))), W);
        ctx.setLineDash([]);
        const bore = at(toN(fov.axis_S));
        if (!fov.head) {
          ctx.fillStyle = col; ctx.beginPath(); ctx.arc(bore[0], bore[1], 3, 0, 2 * Math.PI); ctx.fill();
          label(ctx, dev.name + (ds.label ? ": " + ds.label : ""), bore[0] + 6, bore[1] - 6, col);
        }
        S.overlay.push({ name: fov.label, x: bore[0], y: bore[1], color: col, state: ds.label });
      }
      if (dev.exclusion_deg && $("show-exclusion").checked) {
        ctx.lineWidth = 1; ctx.setLineDash([2, 5]);
        for (const [body, col] of [["sun", COLORS.sunFlag], ["moon", COLORS.moonFlag], ["earth", COLORS.earthFlag]]) {
          const half = dev.exclusion_deg[body];
          if (!half) continue;
          ctx.strokeStyle = col.replace("rgb", "rgba").replace(")", ",0.55)");
          polyline(ctx, coneBoundary([0, 0, 1], half * D2R).map((u) => at(toN(u))), W);
        }
        ctx.setLineDash([]);
      }
    }
  }

  function label(ctx, text, x, y, col) {
    ctx.font = "12px system-ui, sans-serif"; ctx.fillStyle = "rgba(0,0,0,0.6)";
    const w = ctx.measureText(text).width; ctx.fillRect(x - 2, y - 11, w + 4, 14);
    ctx.fillStyle = col; ctx.fillText(text, x, y);
  }

  function drawStars(ctx, M, P, W, H) {
    // Written straight into a pixel buffer: tens of thousands of fillRect calls with their colour strings
    // would cost ten times as much.
    if (!S.stars) return;
    const lim = parseFloat($("mag").value), s = S.stars, n = s.count;
    if (!pano.starImg || pano.starImg.width !== W || pano.starImg.height !== H) {
      pano.starImg = new ImageData(W, H);
      pano.starLayer = document.createElement("canvas"); pano.starLayer.width = W; pano.starLayer.height = H;
    }
    const key = [M.flat().join(), $("pano-proj").value, P === proj.inside ? S.lookAxes.flat().join() + S.lookFov : "",
      lim, W, H].join("|");
    if (pano.starKey === key) { ctx.drawImage(pano.starLayer, 0, 0); return; }  // the sky did not move
    pano.starKey = key;
    const img = pano.starImg, px = new Uint32Array(img.data.buffer);
    px.fill(0);
    let shown = 0;
    const hammer = P === proj.hammer, m = M.flat(), TWO_PI = 2 * Math.PI;
    for (let k = 0; k < n; k++) {
      const mag = s.mag[k];
      if (mag > lim) break;  // brightest first
      const x = s.u[3 * k], y = s.u[3 * k + 1], z = s.u[3 * k + 2];
      // P.fwd inlined (no arrays per star): the same formulas
      const ux = m[0] * x + m[1] * y + m[2] * z, uy = m[3] * x + m[4] * y + m[5] * z, uz = m[6] * x + m[7] * y + m[8] * z;
      const lon = Math.atan2(uy, ux), lat = Math.asin(uz > 1 ? 1 : uz < -1 ? -1 : uz);
      let p0, p1;
      if (P === proj.inside) {
        [p0, p1] = P.fwd([ux, uy, uz], W, H);
        if (p0 < -4 || p0 > W + 4 || p1 < -4 || p1 > H + 4) continue;
      } else if (hammer) {
        const cl = Math.cos(lat), d = Math.sqrt(1 + cl * Math.cos(lon / 2));
        p0 = W / 2 - cl * Math.sin(lon / 2) / d * W / 2; p1 = H / 2 - Math.sin(lat) / d * H / 2;
      } else { p0 = W / 2 - lon / TWO_PI * W; p1 = H / 2 - lat / Math.PI * H; }
      const p = [p0, p1];
      const g = Math.round(Math.max(80, Math.min(255, 290 - 24 * mag)));
      const colour = (255 << 24) | (Math.min(255, g + 25) << 16) | (g << 8) | g;  // little-endian ABGR
      const r = mag < 1.5 ? 2 : mag < 3.5 ? 1 : 0;  // a 5, 3 or 1 pixel square
      const cx = Math.round(p[0]), cy = Math.round(p[1]);
      for (let dy = -r; dy <= r; dy++) {
        const yy = cy + dy;
        if (yy < 0 || yy >= H) continue;
        for (let dx = -r; dx <= r; dx++) {
          const xx = cx + dx;
          if (xx >= 0 && xx < W && (r < 2 || Math.abs(dx) + Math.abs(dy) < 4)) px[yy * W + xx] = colour;
        }
      }
      shown++;
    }
    pano.starLayer.getContext("2d").putImageData(img, 0, 0);
    ctx.drawImage(pano.starLayer, 0, 0);
    $("star-count").textContent = `(${shown} stars)`;
  }

  function drawEarth(ctx, M, P, W, H, r, sunN, i) {
    const sc = 2, w = Math.ceil(W / sc), h = Math.ceil(H / sc);
    if (!pano.earth || pano.earth.width !== w || pano.earth.height !== h) {
      pano.earth = document.createElement("canvas"); pano.earth.width = w; pano.earth.height = h;
      pano.earthCtx = pano.earth.getContext("2d");
    }
    const img = pano.earthCtx.createImageData(w, h), px = img.data, rn = norm(r);
    const cosR = Math.cos(Math.asin(Math.min(1, R_EARTH / rn))), nadir = scale(r, -1 / rn);
    const nadirF = mv(M, nadir), rF = mv(M, r), sunF = mv(M, sunN);
    const CEN = S.store.has("q_EN") ? dcm(S.store.get("q_EN", i)) : null;
    for (let yy = 0; yy < h; yy++) {
      for (let xx = 0; xx < w; xx++) {
        const u = P.inv((xx + 0.5) * sc, (yy + 0.5) * sc, W, H);
        if (!u || dot(u, nadirF) < cosR) continue;
        // the ray r + s u meets the sphere |x| = R at the smaller root
        const b = dot(rF, u), c = rn * rn - R_EARTH * R_EARTH, disc = b * b - c;
        if (disc < 0) continue;
        const s = -b - Math.sqrt(disc), p = [rF[0] + s * u[0], rF[1] + s * u[1], rF[2] + s * u[2]];
        const n = scale(p, 1 / R_EARTH), lit = dot(n, sunF), limb = -dot(n, u);
        const day = Math.max(0, Math.min(1, (lit + 0.05) / 0.1));  // a 6 deg twilight band
        const shade = 0.55 + 0.45 * limb;
        let R = (12 + day * 40) * shade, G = (22 + day * 95) * shade, B = (45 + day * 170) * shade;
        const o = 4 * (yy * w + xx);
        px[o] = R; px[o + 1] = G; px[o + 2] = B; px[o + 3] = 255;
      }
    }
    pano.earthCtx.putImageData(img, 0, 0);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(pano.earth, 0, 0, W, H);
    // coastlines and the 30 deg latitude-longitude net, on the visible side
    if (CEN) {
      const CFE = mm(M, mT(CEN)), net = [];
      for (let lat = -60; lat <= 60; lat += 30) { const r1 = []; for (let lon = -180; lon <= 180; lon += 4) r1.push(lon, lat); net.push(r1); }
      for (let lon = -180; lon < 180; lon += 30) { const r1 = []; for (let lat = -88; lat <= 88; lat += 4) r1.push(lon, lat); net.push(r1); }
      const rings = [[net, "rgba(200,220,255,0.22)"], [S.land || [], "rgba(140,220,150,0.8)"]];
      for (const [set, col] of rings) {
        ctx.strokeStyle = col; ctx.lineWidth = 1;
        for (const ring of set) {
        const pts = [];
        for (let k = 0; k < ring.length; k += 2) {
          const lat = ring[k + 1] * D2R, lon = ring[k] * D2R;
          const e = [R_EARTH * Math.cos(lat) * Math.cos(lon), R_EARTH * Math.cos(lat) * Math.sin(lon), R_EARTH * Math.sin(lat)];
          const pF = mv(CFE, e), d = [pF[0] - rF[0], pF[1] - rF[1], pF[2] - rF[2]];
          pts.push(dot(d, pF) < 0 ? P.fwd(unit(d), W, H) : null);
        }
        polyline(ctx, pts, W);
        }
      }
    }
  }

  // ------------------------------------------------------------------------------------------ attitude panel
  function drawAttitude() {
    const i = S.i, st = S.store;
    if (i < 0) return;
    const R = $("att-frame").value, seq = $("euler-seq").value;
    const C_BN = dcm(st.get("q_BN", i)), C_RN = frameOf(i, R), C = mm(C_BN, mT(C_RN));  // dcm_BR
    const q = quatFromDcm(C), e = eulerFromDcm(C, seq).map((a) => a * R2D);
    const ang = 2 * Math.atan2(Math.hypot(q[1], q[2], q[3]), q[0]), s = Math.hypot(q[1], q[2], q[3]);
    const axis = s > 0 ? [q[1] / s, q[2] / s, q[3] / s] : [1, 0, 0];
    const w = st.get("omega_BN_B", i), rate = norm(w) * R2D;
    const f = (x, d = 3) => (Number.isFinite(x) ? x.toFixed(d) : "–");
    const rows = [
      [`Euler ${seq} (deg)`, e.map((x) => f(x, 2))],
      ["q (w, x, y, z)", q.map((x) => f(x, 5))],
      ["axis", axis.map((x) => f(x, 4))], ["angle (deg)", [f(ang * R2D, 2), "", ""]],
      ["matrix dcm_BR", C[0].map((x) => f(x, 4))], ["", C[1].map((x) => f(x, 4))], ["", C[2].map((x) => f(x, 4))],
      ["ω_BN_B (deg/s)", w.map((x) => f(x * R2D, 3))], ["|ω| (deg/s)", [f(rate, 3), "", ""]],
    ];
    const sep = new Set([1, 2, 4, 7]);
    $("att-table").innerHTML = `<tr><th>body in ${FRAME_NAMES[R]}</th><td></td><td></td><td></td></tr>` +
      rows.map(([k, v], n) => `<tr class="${sep.has(n) ? "sep" : ""}"><th>${k}</th>${v.map((x) => `<td>${x}</td>`).join("")}</tr>`).join("");
    S.attitude = { frame: R, seq, euler_deg: e, q, axis, angle_deg: ang * R2D, dcm: C };
    drawSphere(C, R);
  }

  function drawSphere(C_BR, R) {  // the body axes on a unit sphere in frame R, seen from an oblique point
    const cv = $("sphere"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height, rad = W * 0.36, cx = W / 2, cy = H / 2 + 6;
    ctx.fillStyle = "#05070a"; ctx.fillRect(0, 0, W, H);
    const az = -35 * D2R, el = 25 * D2R;  // view direction
    const view = (v) => {  // orthographic: screen x, y and depth
      const x1 = Math.cos(az) * v[0] - Math.sin(az) * v[1], y1 = Math.sin(az) * v[0] + Math.cos(az) * v[1];
      return [cx + rad * y1, cy - rad * (Math.cos(el) * v[2] - Math.sin(el) * x1), Math.cos(el) * x1 + Math.sin(el) * v[2]];
    };
    const g = ctx.createRadialGradient(cx - rad * 0.3, cy - rad * 0.3, rad * 0.1, cx, cy, rad);
    g.addColorStop(0, "#1c2a40"); g.addColorStop(1, "#0a0f18");
    ctx.fillStyle = g; ctx.beginPath(); ctx.arc(cx, cy, rad, 0, 2 * Math.PI); ctx.fill();
    ctx.strokeStyle = "rgba(150,170,200,0.25)"; ctx.lineWidth = 1;
    for (const plane of [[0, 1], [0, 2], [1, 2]]) {
      ctx.beginPath();
      for (let k = 0; k <= 72; k++) { const a = k * 5 * D2R, v = [0, 0, 0]; v[plane[0]] = Math.cos(a); v[plane[1]] = Math.sin(a); const p = view(v); k ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1]); }
      ctx.stroke();
    }
    const arrow = (v, col, text, width, dash) => {
      const p = view(v), o = view([0, 0, 0]);
      ctx.strokeStyle = col; ctx.lineWidth = width; ctx.setLineDash(dash);
      ctx.globalAlpha = p[2] < 0 ? 0.45 : 1;
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(p[0], p[1]); ctx.stroke();
      ctx.setLineDash([]); ctx.fillStyle = col; ctx.beginPath(); ctx.arc(p[0], p[1], width + 1.5, 0, 2 * Math.PI); ctx.fill();
      ctx.font = "12px system-ui"; ctx.fillText(text, p[0] + 6, p[1] - 4); ctx.globalAlpha = 1;
    };
    const names = { N: ["X", "Y", "Z"], E: ["X", "Y", "Z"], O: ["x", "y", "z nadir"], S: ["E", "S", "D"] }[R];
    for (let a = 0; a < 3; a++) { const v = [0, 0, 0]; v[a] = 1; arrow(v, "rgba(200,200,200,0.8)", FRAME_NAMES[R] + " " + names[a], 1, [3, 3]); }
    // the body axes: rows of dcm_BR are the body axes in R components
    for (let a = 0; a < 3; a++) arrow(C_BR[a], COLORS.axes[a], "body " + "XYZ"[a], 2.5, []);
    // trail of body +X over the last minutes
    const st = S.store, i = S.i, Rsel = R;
    ctx.strokeStyle = "rgba(255,85,85,0.5)"; ctx.lineWidth = 1; ctx.beginPath();
    let first = true;
    for (let k = Math.max(0, i - 300); k <= i; k += 3) {
      const Ck = mm(dcm(st.get("q_BN", k)), mT(frameOf(k, Rsel))), p = view(Ck[0]);
      if (first) { ctx.moveTo(p[0], p[1]); first = false; } else ctx.lineTo(p[0], p[1]);
    }
    ctx.stroke();
  }

  // ------------------------------------------------------------------------------------------ ground track
  function drawGround() {
    const cv = $("ground"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height, st = S.store, i = S.i;
    const X = (lon) => (lon + 180) / 360 * W, Y = (lat) => (90 - lat) / 180 * H;
    ctx.fillStyle = "#0b1a2e"; ctx.fillRect(0, 0, W, H);
    if (i < 0) return;
    if (S.land) {
      if (!S.landLayer || S.landLayer.width !== W) {  // the continents do not move: drawn once
        const layer = S.landLayer = document.createElement("canvas"); layer.width = W; layer.height = H;
        const lc = layer.getContext("2d");
        lc.fillStyle = "rgb(52,84,62)"; lc.strokeStyle = "rgba(140,200,150,0.8)"; lc.lineWidth = 0.8;
        for (const ring of S.land) {
          // Rings crossing the date line are unwrapped and drawn again one turn to each side (the canvas clips).
          const xs = [], ys = [];
          let lon0 = ring[0];
          for (let k = 0; k < ring.length; k += 2) {
            let lon = ring[k];
            while (lon - lon0 > 180) lon -= 360;
            while (lon - lon0 < -180) lon += 360;
            lon0 = lon; xs.push(X(lon)); ys.push(Y(ring[k + 1]));
          }
          for (const shift of [-W, 0, W]) {
            lc.beginPath();
            xs.forEach((x, k) => (k ? lc.lineTo(x + shift, ys[k]) : lc.moveTo(x + shift, ys[k])));
            lc.fill(); lc.stroke();
          }
        }
      }
      ctx.drawImage(S.landLayer, 0, 0);
    }
    // night by the sub-solar point, as a translucent layer
    const CEN = dcm(st.get("q_EN", i)), sE = mv(CEN, st.get("sun_N", i)), nw = W >> 2, nh = H >> 2;
    if (!S.night || S.night.width !== nw) { S.night = document.createElement("canvas"); S.night.width = nw; S.night.height = nh; }
    const nctx = S.night.getContext("2d"), img = nctx.createImageData(nw, nh), px = img.data;
    for (let y = 0; y < nh; y++) {
      const lat = (90 - (y + 0.5) / nh * 180) * D2R;
      for (let x = 0; x < nw; x++) {
        const lon = ((x + 0.5) / nw * 360 - 180) * D2R;
        const c = Math.cos(lat) * Math.cos(lon) * sE[0] + Math.cos(lat) * Math.sin(lon) * sE[1] + Math.sin(lat) * sE[2];
        px[4 * (y * nw + x) + 3] = 175 * Math.max(0, Math.min(1, (0.05 - c) / 0.1));
      }
    }
    nctx.putImageData(img, 0, 0);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(S.night, 0, 0, W, H);
    ctx.strokeStyle = "rgba(255,255,255,0.12)"; ctx.lineWidth = 1;
    for (let lon = -150; lon < 180; lon += 30) { ctx.beginPath(); ctx.moveTo(X(lon), 0); ctx.lineTo(X(lon), H); ctx.stroke(); }
    for (let lat = -60; lat <= 60; lat += 30) { ctx.beginPath(); ctx.moveTo(0, Y(lat)); ctx.lineTo(W, Y(lat)); ctx.stroke(); }
    // the track, sunlit or in the Earth's shadow; past solid, future faint
    const lat = st.cols.lat_deg.data, lon = st.cols.lon_deg.data, nu = st.cols.sun_fraction ? st.cols.sun_fraction.data : null;
    ctx.lineWidth = 2;
    for (const [lit, past, col] of [[true, false, "rgba(255,204,51,0.3)"], [false, false, "rgba(120,140,185,0.3)"],
      [true, true, "rgb(255,204,51)"], [false, true, "rgb(120,140,185)"]]) {
      ctx.strokeStyle = col; ctx.beginPath();
      for (let k = 1; k < st.n; k++) {
        if (Math.abs(lon[k] - lon[k - 1]) > 180 || (!nu || nu[k] > 0.5) !== lit || (k <= i) !== past) continue;
        ctx.moveTo(X(lon[k - 1]), Y(lat[k - 1])); ctx.lineTo(X(lon[k]), Y(lat[k]));
      }
      ctx.stroke();
    }
    const x = X(lon[i]), y = Y(lat[i]);
    ctx.fillStyle = "#fff"; ctx.strokeStyle = "#000"; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.arc(x, y, 6, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
    const text = `${lat[i].toFixed(2)}°, ${lon[i].toFixed(2)}°`;
    ctx.font = "12px system-ui, sans-serif";
    label(ctx, text, x + 9 + ctx.measureText(text).width > W - 4 ? x - 13 - ctx.measureText(text).width : x + 9, y - 6, "#fff");
    const subsolar = [Math.asin(sE[2]) * R2D, Math.atan2(sE[1], sE[0]) * R2D];
    ctx.fillStyle = COLORS.sun; ctx.beginPath(); ctx.arc(X(subsolar[1]), Y(subsolar[0]), 5, 0, 2 * Math.PI); ctx.fill();
  }

  // ------------------------------------------------------------------------------------------ 3-D view
  // The spacecraft in its orbit around the Earth, in GCRS, lengths in Earth radii, seen by a perspective camera
  // that turns about the Earth's centre or the spacecraft (drag to turn, wheel to zoom): the Earth lit by the Sun
  // with its coastlines, the orbit (the run's track, hidden behind the Earth), the body axes, the momentum and
  // torque vectors recorded or derived (drawn at a fixed length, their size written beside), the fields of view
  // as cones (rectangles as pyramids) in the device's state colour. The spacecraft and its vectors are not to
  // scale (a spacecraft is metres in a 6378 km Earth).
  const view3 = { az: -60 * D2R, el: 25 * D2R, dist: { earth: 5.0, sc: 0.45 }, fov: 40 * D2R };
  function camera3(W, H) {
    const center = $("v3-center").value, i = S.i, r = scale(S.store.get("r_BN_N", i), 1 / R_EARTH);
    const c = center === "sc" ? r : [0, 0, 0], D = view3.dist[center], az = view3.az, el = view3.el;
    const back = [Math.cos(el) * Math.cos(az), Math.cos(el) * Math.sin(az), Math.sin(el)];
    const right = [-Math.sin(az), Math.cos(az), 0], up = cross(back, right);
    const eye = [0, 1, 2].map((j) => c[j] + D * back[j]), f = H / 2 / Math.tan(view3.fov / 2);
    const cam = { c, D, back, right, up, eye, f, W, H };
    cam.px = (p) => {  // world (Earth radii) -> [x, y, depth]; null behind the camera
      const d = [p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]], z = -dot(d, back);
      if (z < 1e-3) return null;
      return [W / 2 + f * dot(d, right) / z, H / 2 - f * dot(d, up) / z, z];
    };
    cam.hidden = (p) => {  // behind the Earth as the camera sees it
      const d = [p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]], L = norm(d), u = scale(d, 1 / L);
      const b = dot(eye, u), disc = b * b - (dot(eye, eye) - 1);
      if (disc < 0) return false;
      const t = -b - Math.sqrt(disc);
      return t > 0 && t < L - 1e-6;
    };
    return cam;
  }
  function draw3d() {
    const cv = $("orbit3d"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height, st = S.store, i = S.i;
    ctx.fillStyle = "#03050a"; ctx.fillRect(0, 0, W, H);
    if (i < 0) return;
    const cam = camera3(W, H), sunN = st.get("sun_N", i), C_BN = dcm(st.get("q_BN", i));
    const r = scale(st.get("r_BN_N", i), 1 / R_EARTH);
    drawEarth3d(ctx, cam, sunN, i);
    // the orbit: the run's track, solid where it was flown, faint ahead; hidden behind the Earth
    const n = st.n, step = Math.max(1, Math.floor(n / 1500));
    for (const [past, col] of [[false, "rgba(200,210,230,0.25)"], [true, "rgba(255,220,120,0.85)"]]) {
      ctx.strokeStyle = col; ctx.lineWidth = 1.5; ctx.beginPath();
      let pen = false;
      for (let k = 0; k < n; k += step) {
        if ((k <= i) !== past) { pen = false; continue; }
        const p = scale(st.get("r_BN_N", k), 1 / R_EARTH), q = cam.px(p);
        if (!q || cam.hidden(p)) { pen = false; continue; }
        if (pen) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]);
        pen = true;
      }
      ctx.stroke();
    }
    // the Sun's direction, from the Earth's centre to the edge of the view
    const sp = cam.px(scale(sunN, 3.0)), o = cam.px([0, 0, 0]);
    if (sp && o) { ctx.strokeStyle = "rgba(255,200,0,0.5)"; ctx.setLineDash([3, 5]); ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(sp[0], sp[1]); ctx.stroke(); ctx.setLineDash([]); label(ctx, "Sun", sp[0] + 4, sp[1], COLORS.sun); }
    const sc = cam.px(r), L = $("v3-center").value === "sc" ? 0.12 : 0.45;  // the drawn length of a vector
    const info = { sc: sc ? [sc[0], sc[1]] : null, hidden: cam.hidden(r), axes: [], vectors: [], cones: 0, cam: { az: view3.az, el: view3.el, dist: cam.D, fov: view3.fov, center: $("v3-center").value } };
    S.view3d = info;
    if (!sc) return;
    ctx.globalAlpha = info.hidden ? 0.35 : 1;
    // fields of view as cones (a rectangle as a pyramid), in the device's state colour
    for (const dev of S.meta.devices) {
      if (!dev.fovs.length) continue;
      const ds = deviceState(dev, i), C_SB = dcm(dev.q_SB), toN = (uS) => mtv(C_BN, mtv(C_SB, uS));
      for (const fov of dev.fovs) {
        if (fov.head) continue;
        const bound = fov.shape === "rect" ? rectBoundary(fov.fov_deg, 1) : coneBoundary(fov.axis_S, fov.half_deg * D2R, 32);
        const len = L * 0.8, ends = bound.map((u) => cam.px([0, 1, 2].map((j) => r[j] + len * toN(u)[j])));
        ctx.strokeStyle = ds.color; ctx.fillStyle = ds.color.replace("rgb", "rgba").replace(")", ",0.12)"); ctx.lineWidth = 1.2;
        ctx.beginPath(); ends.forEach((e, k) => { if (e) { if (k) ctx.lineTo(e[0], e[1]); else ctx.moveTo(e[0], e[1]); } }); ctx.closePath(); ctx.fill(); ctx.stroke();
        ctx.beginPath();
        for (let k = 0; k < ends.length - 1; k += Math.max(1, Math.floor((ends.length - 1) / 4))) if (ends[k]) { ctx.moveTo(sc[0], sc[1]); ctx.lineTo(ends[k][0], ends[k][1]); }
        ctx.stroke();
        info.cones++;
      }
    }
    const arrow = (vN, col, text, width, dash = []) => {
      const e = cam.px([0, 1, 2].map((j) => r[j] + vN[j])); if (!e) return null;
      ctx.strokeStyle = col; ctx.fillStyle = col; ctx.lineWidth = width; ctx.setLineDash(dash);
      ctx.beginPath(); ctx.moveTo(sc[0], sc[1]); ctx.lineTo(e[0], e[1]); ctx.stroke(); ctx.setLineDash([]);
      const a = Math.atan2(e[1] - sc[1], e[0] - sc[0]);
      ctx.beginPath(); ctx.moveTo(e[0], e[1]); ctx.lineTo(e[0] - 9 * Math.cos(a - 0.4), e[1] - 9 * Math.sin(a - 0.4)); ctx.lineTo(e[0] - 9 * Math.cos(a + 0.4), e[1] - 9 * Math.sin(a + 0.4)); ctx.fill();
      if (text) label(ctx, text, e[0] + 5, e[1] - 4, col);
      return [e[0], e[1]];
    };
    // the spacecraft: a small cube along its body axes, then the axes
    const half = L * 0.12, corners = [];
    for (const a of [-1, 1]) for (const b of [-1, 1]) for (const c of [-1, 1]) corners.push(cam.px([0, 1, 2].map((j) => r[j] + half * (a * C_BN[0][j] + b * C_BN[1][j] + c * C_BN[2][j]))));
    ctx.strokeStyle = "#c9d1d9"; ctx.fillStyle = "rgba(170,180,195,0.85)"; ctx.lineWidth = 1;
    if (corners.every(Boolean)) {
      for (const [p, q] of [[0, 1], [1, 3], [3, 2], [2, 0], [4, 5], [5, 7], [7, 6], [6, 4], [0, 4], [1, 5], [2, 6], [3, 7]]) { ctx.beginPath(); ctx.moveTo(corners[p][0], corners[p][1]); ctx.lineTo(corners[q][0], corners[q][1]); ctx.stroke(); }
    }
    ctx.beginPath(); ctx.arc(sc[0], sc[1], 3, 0, 2 * Math.PI); ctx.fill();
    for (let a = 0; a < 3; a++) info.axes.push(arrow(scale(C_BN[a], L), COLORS.axes[a], "+" + "XYZ"[a], 2));
    // momentum and torques (body components rotated into GCRS), each at a fixed drawn length
    const vecs = [["h_total_B", "H", "rgb(255,255,255)", "N m s"], ["h_wheels_B", "h wheels", "rgb(150,200,255)", "N m s"],
      ["torque_wheels_B", "τ wheels", "rgb(255,150,60)", "N m"], ["torque_mtq_B", "τ coils", "rgb(230,120,255)", "N m"]];
    for (const [col, name, colour, unitText] of vecs) {
      if (!st.has(col)) continue;
      const vB = st.get(col, i), m = norm(vB);
      if (!(m > 0)) continue;
      const end = arrow(scale(mtv(C_BN, vB), 0.8 * L / m), colour, `${name} ${fmt(m)} ${unitText}`, 2.5, col.startsWith("torque") ? [5, 3] : []);
      info.vectors.push({ col, end, magnitude: m });
    }
    ctx.globalAlpha = 1;
    info.drawn = (info.drawn || 0) + 1;
  }
  function drawEarth3d(ctx, cam, sunN, i) {
    // per pixel of a third-size raster: the ray from the eye meets the unit sphere; lit by the Sun
    const sc = 3, W = cam.W, H = cam.H, w = Math.ceil(W / sc), h = Math.ceil(H / sc);
    if (!view3.layer || view3.layer.width !== w) { view3.layer = document.createElement("canvas"); view3.layer.width = w; view3.layer.height = h; }
    const lctx = view3.layer.getContext("2d"), img = lctx.createImageData(w, h), px = img.data, eye = cam.eye, ee = dot(eye, eye) - 1;
    const [rx, ry, rz] = cam.right, [ux, uy, uz] = cam.up, [bx, by, bz] = cam.back, [ex, ey, ez] = eye, [sx, sy, sz] = sunN;
    for (let yy = 0; yy < h; yy++) {  // scalars only in this loop: it runs for every pixel of the raster
      const Y = (H / 2 - (yy + 0.5) * sc) / cam.f;
      for (let xx = 0; xx < w; xx++) {
        const X = ((xx + 0.5) * sc - W / 2) / cam.f;
        let dx = X * rx + Y * ux - bx, dy = X * ry + Y * uy - by, dz = X * rz + Y * uz - bz;
        const dn = Math.sqrt(dx * dx + dy * dy + dz * dz); dx /= dn; dy /= dn; dz /= dn;
        const b = ex * dx + ey * dy + ez * dz, disc = b * b - ee;
        if (disc < 0) continue;
        const t = -b - Math.sqrt(disc);
        if (t <= 0) continue;
        const px0 = ex + t * dx, py0 = ey + t * dy, pz0 = ez + t * dz;
        const day = Math.max(0, Math.min(1, (px0 * sx + py0 * sy + pz0 * sz + 0.05) / 0.1));
        const shade = 0.55 - 0.45 * (px0 * dx + py0 * dy + pz0 * dz);
        const o = 4 * (yy * w + xx);
        px[o] = (12 + day * 40) * shade; px[o + 1] = (22 + day * 95) * shade; px[o + 2] = (45 + day * 170) * shade; px[o + 3] = 255;
      }
    }
    lctx.putImageData(img, 0, 0);
    ctx.imageSmoothingEnabled = true;
    ctx.drawImage(view3.layer, 0, 0, W, H);
    if (!S.land || !S.store.has("q_EN")) return;
    const CNE = mT(dcm(S.store.get("q_EN", i)));  // ITRS -> GCRS
    if (!view3.landUnits) {  // the coastlines' points as unit vectors in ITRS, once
      view3.landUnits = S.land.map((ring) => {
        const u = new Float64Array(ring.length / 2 * 3);
        for (let k = 0; k < ring.length; k += 2) {
          const lat = ring[k + 1] * D2R, lon = ring[k] * D2R, o = k / 2 * 3;
          u[o] = Math.cos(lat) * Math.cos(lon); u[o + 1] = Math.cos(lat) * Math.sin(lon); u[o + 2] = Math.sin(lat);
        }
        return u;
      });
    }
    ctx.strokeStyle = "rgba(140,220,150,0.75)"; ctx.lineWidth = 1;
    for (const ring of view3.landUnits) {
      ctx.beginPath();
      let pen = false;
      for (let o = 0; o < ring.length; o += 3) {
        const x = ring[o], y = ring[o + 1], z = ring[o + 2];
        const p = [CNE[0][0] * x + CNE[0][1] * y + CNE[0][2] * z, CNE[1][0] * x + CNE[1][1] * y + CNE[1][2] * z, CNE[2][0] * x + CNE[2][1] * y + CNE[2][2] * z];
        const q = p[0] * eye[0] + p[1] * eye[1] + p[2] * eye[2] > 1 ? cam.px(p) : null;  // the side facing the eye
        if (!q) { pen = false; continue; }
        if (pen) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]);
        pen = true;
      }
      ctx.stroke();
    }
  }
  function setup3d() {
    const cv = $("orbit3d");
    let drag = null;
    cv.addEventListener("pointerdown", (ev) => { drag = [ev.clientX, ev.clientY, view3.az, view3.el]; cv.setPointerCapture(ev.pointerId); });
    cv.addEventListener("pointermove", (ev) => {
      if (!drag) return;
      view3.az = drag[2] - (ev.clientX - drag[0]) * 0.01; view3.el = Math.max(-1.5, Math.min(1.5, drag[3] + (ev.clientY - drag[1]) * 0.01));
      redraw();
    });
    cv.addEventListener("pointerup", () => { drag = null; });
    cv.addEventListener("wheel", (ev) => {
      ev.preventDefault();
      const c = $("v3-center").value, lo = c === "sc" ? 0.15 : 1.6;
      view3.dist[c] = Math.max(lo, Math.min(30, view3.dist[c] * Math.exp(ev.deltaY * 0.001)));
      redraw();
    }, { passive: false });
    $("v3-center").addEventListener("change", redraw);
  }
  S.view3 = view3; S.camera3 = camera3;

  // ------------------------------------------------------------------------------------------ time plots
  class Plot {
    constructor(title, series, opts = {}) {
      this.title = title; this.series = series; this.opts = opts;
      const box = document.createElement("div"); box.className = "plot";
      box.innerHTML = `<div class="head"><span>${title}</span><span class="val"></span></div>`;
      this.canvas = document.createElement("canvas"); this.canvas.width = 560; this.canvas.height = 170;
      box.appendChild(this.canvas); $("plots").appendChild(box);
      this.val = box.querySelector(".val");
      this.canvas.addEventListener("click", (ev) => {
        const rect = this.canvas.getBoundingClientRect(), fx = (ev.clientX - rect.left) / rect.width * this.canvas.width;
        if (this.t0 !== undefined) seek(this.t0 + (fx - 46) / (this.canvas.width - 56) * (this.t1 - this.t0));
      });
    }
    value(s, k) {  // series value at sample k
      const st = S.store, c = st.cols[s.col];
      if (!c) return NaN;
      let v;
      if (s.fn) v = s.fn(k); else v = c.data[k * c.w + (s.idx || 0)];
      return v * (s.scale || 1);
    }
    draw() {
      // The data layer is drawn again only when samples arrived; moving in time only moves the cursor.
      const st = S.store, key = `${st.n}/${S.faultMarks.length}`;
      if (!this.layer || this.key !== key) {
        this.layer = this.layer || document.createElement("canvas");
        this.layer.width = this.canvas.width; this.layer.height = this.canvas.height;
        this.key = key; this.drawData(this.layer);
      }
      const ctx = this.canvas.getContext("2d");
      ctx.drawImage(this.layer, 0, 0);
      if (S.i >= 0 && this.X) { ctx.strokeStyle = "#f0f6fc"; ctx.lineWidth = 1; ctx.beginPath(); ctx.moveTo(this.X(S.t), 8); ctx.lineTo(this.X(S.t), this.canvas.height - 20); ctx.stroke(); }
      const series = this.series.filter((s) => st.cols[s.col]);
      this.val.textContent = series.map((s) => `${s.label} ${fmt(this.value(s, Math.max(0, S.i)))}`).join("  ");
    }
    drawData(cv) {
      const ctx = cv.getContext("2d"), W = cv.width, H = cv.height, st = S.store;
      const L = 46, Rm = 10, T = 8, B = 20, pw = W - L - Rm, ph = H - T - B;
      ctx.fillStyle = "#0b0f14"; ctx.fillRect(0, 0, W, H);
      const series = this.series.filter((s) => st.cols[s.col]);
      if (!st.n || !series.length) { this.X = null; ctx.fillStyle = "#555"; ctx.font = "12px system-ui"; ctx.fillText("not recorded in this run", L + 10, H / 2); return; }
      const t0 = st.t(0), t1 = Math.max(st.t(st.n - 1), this.opts.tEnd || 0, t0 + 1e-6);
      this.t0 = t0; this.t1 = t1;
      let lo = Infinity, hi = -Infinity;
      for (const s of series) for (let k = 0; k < st.n; k++) { let v = this.value(s, k); if (this.opts.log) v = v > 0 ? Math.log10(v) : NaN; if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); } }
      if (this.opts.yRange) [lo, hi] = this.opts.yRange;
      for (const v of this.opts.yInclude || []) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
      if (!Number.isFinite(lo)) { lo = 0; hi = 1; }
      if (hi - lo < 1e-12) { hi += 0.5; lo -= 0.5; }
      const pad = (hi - lo) * 0.06; lo -= pad; hi += pad;
      const X = (t) => L + (t - t0) / (t1 - t0) * pw, Y = (v) => T + (hi - v) / (hi - lo) * ph;
      this.X = X;
      ctx.strokeStyle = "#222a33"; ctx.fillStyle = "#7d8590"; ctx.font = "10px system-ui"; ctx.lineWidth = 1;
      const yt = this.opts.log ? logTicks(lo, hi) : ticks(lo, hi, 4).filter((v) => !this.opts.integer || Number.isInteger(v));
      for (const v of yt) { ctx.beginPath(); ctx.moveTo(L, Y(v)); ctx.lineTo(W - Rm, Y(v)); ctx.stroke(); ctx.fillText(fmt(this.opts.log ? Math.pow(10, v) : v), 2, Y(v) + 3); }
      for (const t of ticks(t0, t1, 6)) { ctx.beginPath(); ctx.moveTo(X(t), T); ctx.lineTo(X(t), T + ph); ctx.stroke(); ctx.fillText(fmt(t) + " s", X(t) - 10, H - 5); }
      for (const s of series) {
        ctx.strokeStyle = s.color; ctx.lineWidth = s.width || 1.3; ctx.globalAlpha = s.alpha || 1; ctx.beginPath();
        let pen = false, lastX = -1, mn = 0, mx = 0;
        for (let k = 0; k < st.n; k++) {
          let v = this.value(s, k); if (this.opts.log) v = v > 0 ? Math.log10(v) : NaN;
          if (!Number.isFinite(v)) { pen = false; continue; }
          const x = Math.round(X(st.t(k))), y = Y(v);
          if (pen && x === lastX) { if (y < mn) { mn = y; ctx.lineTo(x, y); } if (y > mx) { mx = y; ctx.lineTo(x, y); } continue; }
          if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
          pen = true; lastX = x; mn = mx = y;
        }
        ctx.stroke(); ctx.globalAlpha = 1;
      }
      drawFaultMarks(ctx, X, t0, t1, T, ph);
      if (this.opts.limits) for (const [v, text] of this.opts.limits) {
        const yv = this.opts.log ? Math.log10(v) : v; if (yv < lo || yv > hi) continue;
        ctx.strokeStyle = "rgba(255,90,90,0.7)"; ctx.setLineDash([5, 4]); ctx.beginPath(); ctx.moveTo(L, Y(yv)); ctx.lineTo(W - Rm, Y(yv)); ctx.stroke(); ctx.setLineDash([]);
        ctx.fillStyle = "rgba(255,120,120,0.9)"; ctx.fillText(text, W - Rm - ctx.measureText(text).width - 2, Y(yv) - 3);
      }
      let lx = L + 6;
      ctx.font = "11px system-ui";
      for (const s of series) { ctx.fillStyle = s.color; ctx.fillText(s.label, lx, T + 12); lx += ctx.measureText(s.label).width + 12; }
    }
  }

  class Strip {  // validity of every tracker and sun sensor over time, coloured as on the panorama
    constructor(devs) {
      this.devs = devs;
      const box = document.createElement("div"); box.className = "plot";
      box.innerHTML = `<div class="head"><span>sensor validity (green valid; red Sun, orange Moon, blue Earth, violet rate in field)</span></div>`;
      this.canvas = document.createElement("canvas"); this.canvas.width = 560; this.canvas.height = 30 + 22 * Math.max(1, devs.length);
      box.appendChild(this.canvas); $("plots").appendChild(box);
    }
    draw() {
      const st = S.store, ctx = this.canvas.getContext("2d");
      if (!this.layer || this.key !== st.n) {
        this.layer = this.layer || document.createElement("canvas");
        this.layer.width = this.canvas.width; this.layer.height = this.canvas.height;
        this.key = st.n; this.drawData(this.layer);
      }
      ctx.drawImage(this.layer, 0, 0);
      if (this.X) { ctx.strokeStyle = "#f0f6fc"; ctx.lineWidth = 1; ctx.beginPath(); ctx.moveTo(this.X(S.t), 2); ctx.lineTo(this.X(S.t), this.canvas.height - 14); ctx.stroke(); }
    }
    drawData(cv) {
      const ctx = cv.getContext("2d"), W = cv.width, H = cv.height, st = S.store, L = 46, pw = W - L - 10;
      ctx.fillStyle = "#0b0f14"; ctx.fillRect(0, 0, W, H);
      if (!st.n) return;
      const t0 = st.t(0), t1 = Math.max(st.t(st.n - 1), t0 + 1e-6), X = (t) => L + (t - t0) / (t1 - t0) * pw;
      this.X = X;
      this.devs.forEach((dev, r) => {
        const y = 6 + 22 * r;
        ctx.fillStyle = "#7d8590"; ctx.font = "11px system-ui"; ctx.fillText(dev.name, 2, y + 13);
        let k0 = 0, c0 = deviceState(dev, 0).color;  // runs of one state as one rectangle
        for (let k = 1; k <= st.n; k++) {
          const c = k < st.n ? deviceState(dev, k).color : null;
          if (c === c0) continue;
          const x0 = X(st.t(k0)), x1 = k < st.n ? X(st.t(k)) : X(st.t(st.n - 1)) + 1;
          ctx.fillStyle = c0; ctx.fillRect(x0, y, Math.max(1, x1 - x0), 16);
          k0 = k; c0 = c;
        }
      });
      ctx.fillStyle = "#7d8590"; ctx.font = "10px system-ui";
      for (const t of ticks(t0, t1, 6)) ctx.fillText(fmt(t) + " s", X(t) - 10, H - 4);
    }
  }

  function ticks(lo, hi, n) {
    const step0 = (hi - lo) / n, mag = Math.pow(10, Math.floor(Math.log10(step0))), m = step0 / mag;
    const step = (m < 1.5 ? 1 : m < 3 ? 2 : m < 7 ? 5 : 10) * mag, out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9 * step; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
    return out;
  }
  function logTicks(lo, hi) {  // whole decades, every other one when there are many
    const a = Math.ceil(lo), b = Math.floor(hi), out = [];
    const step = b - a > 5 ? 2 : 1;
    for (let v = a; v <= b; v += step) out.push(v);
    return out.length ? out : ticks(lo, hi, 3);
  }
  function fmt(v) {
    if (!Number.isFinite(v)) return "–";
    const a = Math.abs(v);
    return a === 0 ? "0" : a >= 1e4 || a < 1e-2 ? v.toExponential(2) : a >= 100 ? v.toFixed(0) : a >= 10 ? v.toFixed(1) : v.toFixed(3);
  }

  function buildPlots() {
    $("plots").innerHTML = "";
    const st = S.store, cols = Object.keys(st.cols), devs = S.meta.devices, crit = S.meta.criteria || [];
    const rateLimits = crit.filter((c) => /rate_deg_s/.test(c.metric) && c.max !== null).map((c) => [c.max, c.name]);
    const plots = [new Plot("body rate |ω| (deg/s, log)", [{ col: "omega_BN_B", label: "|ω|", color: "#58a6ff",
      fn: (k) => { const d = st.cols.omega_BN_B.data; return Math.hypot(d[3 * k], d[3 * k + 1], d[3 * k + 2]) * R2D; } }], { log: true, limits: rateLimits })];
    const comp = ["x", "y", "z"], ccol = ["#ff6b6b", "#51cf66", "#4dabf7"];
    plots.push(new Plot("body rate ω_BN_B (deg/s)", comp.map((c, j) => ({ col: "omega_BN_B", idx: j, label: c, color: ccol[j], scale: R2D }))));
    // The controller's pointing error (true attitude against adcs_q_RN) and knowledge error (against
    // adcs_q_BN_est), derived by the server as the verdict scores them; a sensor's declared error columns only
    // where its solution is valid (NAME.COLUMN.valid_only); any other recorded error column as it is.
    const knowledge = [{ col: "pointing_error_arcsec", label: "pointing (controller)", color: "#ff6b6b", width: 2.2 },
      { col: "knowledge_error_arcsec", label: "knowledge (estimate)", color: "#63e6be", width: 1.8 }];
    const errColors = ["#ffa94d", "#da77f2", "#ffd43b", "#74c0fc"];
    for (const d of devs) {  // the error columns each kind declares (view.json: error_columns)
      (d.error_columns || []).forEach((c, j) => knowledge.push({ col: d.name + "." + c + ".valid_only", label: d.name + " " + c.replace(/^err_/, "") + " (valid)", color: errColors[j % errColors.length], width: 1, alpha: 0.5 }));
    }
    knowledge.push(knowledge.shift(), knowledge.shift());  // the controller's errors drawn last, on top
    const derived = new Set(knowledge.map((k) => k.col));
    const pointing = cols.filter((c) => /pointing_err|att_err|knowledge_err/.test(c) && !derived.has(c));
    for (const c of pointing) knowledge.push({ col: c, label: c, color: "#dee2e6" });
    const errLimits = crit.filter((c) => /(pointing|knowledge)_error_arcsec/.test(c.metric) && c.max !== null).map((c) => [c.max, c.name]);
    plots.push(new Plot("pointing and knowledge error (arcsec, log)", knowledge, { log: true, limits: errLimits, id: "pointing" }));
    // The vector plots the kinds declare (view.json: plots), one panel per title for all their devices; a panel
    // draws its fallback column (what the controller commanded) when no device records one.
    const panels = new Map();
    for (const d of devs) {
      for (const p of d.plots || []) {
        const panel = panels.get(p.title) || { unit: p.unit, fallback: p.fallback, cols: [] };
        if (cols.includes(d.name + "." + p.column)) panel.cols.push(d.name + "." + p.column);
        panels.set(p.title, panel);
      }
    }
    for (const [title, panel] of panels) {
      const shown = panel.cols.length ? panel.cols : cols.filter((c) => c === panel.fallback);
      plots.push(new Plot(`${title} ${shown.join(", ")} (${panel.unit})`, shown.flatMap((c) => comp.map((a, j) => ({ col: c, idx: j, label: a, color: ccol[j] })))));
    }
    // Wheel speeds in one unit, rpm, against each wheel's rated limit (its datasheet's max_speed_rad_s).
    const RPM = 60 / (2 * Math.PI), wcol = ["#ff6b6b", "#51cf66", "#4dabf7", "#ffd43b", "#da77f2", "#ffa94d"];
    const wheels = cols.filter((c) => /(wheel|rw).*(speed|omega)|\.speed/.test(c));
    const wheelLimits = new Map();
    for (const d of devs) { const m = d.datasheet && d.datasheet.max_speed_rad_s; if (m) wheelLimits.set(Math.round(m * RPM), d.name); }
    const limits = [...wheelLimits.keys()].flatMap((v) => [[v, `+${v} rpm limit`], [-v, `−${v} rpm limit`]]);
    plots.push(new Plot("wheel speeds (rpm)", wheels.map((c, n) => ({ col: c, label: c.split(".")[0], color: wcol[n % wcol.length], scale: /_rpm$/.test(c) ? 1 : RPM, unit: "rpm" })),
      { limits, yInclude: limits.map((l) => l[0]), id: "wheels" }));
    if (cols.includes("adcs_mode")) {
      plots.push(new Plot("controller mode (adcs_mode)" + (S.modeNames.size ? ": " + [...S.modeNames].map(([k, v]) => `${k} ${v}`).join(", ") : ""),
        [{ col: "adcs_mode", label: "mode", color: "#ffd43b" }], { id: "mode", integer: true }));
    }
    plots.push(new Plot("Sun visible fraction (Earth shadow)", [{ col: "sun_fraction", label: "ν", color: "#ffcc33" }], { yRange: [0, 1] }));
    S.plots = plots;
    S.plotsHaveData = st.n > 0;
    const sensed = devs.filter((d) => d.state);
    S.strip = sensed.length ? new Strip(sensed) : null;
  }

  // ------------------------------------------------------------------------------------------ events
  function drawVerdict() {
    const sum = S.meta.summary;
    if (!sum) return;
    const box = $("verdict");
    box.textContent = "";
    const head = document.createElement("div");
    head.className = sum.pass ? "pass" : "fail";
    head.textContent = `${sum.pass ? "PASS" : "FAIL"} (${sum.status})` + (sum.error ? `: ${sum.error}` : "");
    box.appendChild(head);
    for (const c of sum.criteria || []) {
      const div = document.createElement("div");
      div.className = c.pass ? "pass" : "fail";
      const lim = Object.entries(c.limit || {}).map(([k, v]) => `${k} ${v}`).join(", ");
      // A value the run could not measure (a tracker that never solved) comes as null: "n/a", and why if the
      // summary says.
      const value = typeof c.value === "number" && Number.isFinite(c.value) ? `${fmt(c.value)} ${c.unit || ""}` : "n/a";
      div.textContent = `${c.pass ? "✓" : "✗"} ${c.name}: ${value} (${lim})`;
      div.title = div.textContent + (c.reason ? ": " + c.reason : "");
      if (c.reason) {
        const why = document.createElement("span");
        why.className = "reason"; why.textContent = c.reason;
        div.appendChild(why);
      }
      box.appendChild(div);
    }
  }

  function drawEvents(force) {
    const box = $("events");
    if (force || box.childElementCount !== S.events.length) {
      box.innerHTML = "";
      for (const ev of S.events) {
        const div = document.createElement("div"), t = Number.isFinite(ev.t_s) ? ev.t_s : undefined;
        div.innerHTML = `<span class="k">${t !== undefined ? "t=" + (+t).toFixed(1) + " s" : ""} ${ev.kind}</span> `;
        div.appendChild(document.createTextNode(ev.message || ""));
        div.title = ev.message || "";
        if (t !== undefined) div.onclick = () => seek(+t);
        div.dataset.t = t !== undefined ? t : "";
        box.appendChild(div);
      }
    }
    for (const div of box.children) div.className = div.dataset.t === "" || +div.dataset.t <= S.t + 1e-6 ? "past" : "future";
  }

  // ------------------------------------------------------------------------------------------ faults
  // Fault events (fault_injected, fault_cleared in the event log) as bars on the timeline under the header, as
  // vertical markers on every time plot and in the fault panel, from which a live run takes new faults
  // (POST /api/faults, under the same token rules as Pause and Stop).
  const FAULT_RGB = "rgb(255,120,0)", CLEARED_RGB = "rgb(0,200,200)";
  const finite = (v) => (typeof v === "number" && Number.isFinite(v) ? v : null);
  function faultList(events) {  // stand.view.state.fault_list
    const out = [];
    for (const ev of events) {
      if (ev.kind === "fault_injected") {
        out.push({ name: ev.fault, type: ev.type, device: ev.device, params: ev.params || {}, injected_s: finite(ev.t_s), cleared_s: null, active: true });
      } else if (ev.kind === "fault_cleared") {
        const f = out.slice().reverse().find((x) => x.name === ev.fault && x.active);
        if (f) { f.cleared_s = finite(ev.t_s); f.active = false; }
      }
    }
    return out;
  }
  function eventsChanged() {
    S.eventsSeen = S.events.length; S.statusSeen = S.status;
    S.faults = faultList(S.events);
    S.faultMarks = S.events.filter((e) => (e.kind === "fault_injected" || e.kind === "fault_cleared") && finite(e.t_s) !== null)
      .map((e) => ({ t: e.t_s, kind: e.kind, name: e.fault }));
    drawFaultList();
  }
  function drawFaultMarks(ctx, X, t0, t1, top, height) {  // on a plot's data layer
    ctx.save();
    ctx.font = "10px system-ui"; ctx.lineWidth = 2; ctx.setLineDash([6, 3]);
    for (const m of S.faultMarks) {
      if (m.t < t0 || m.t > t1) continue;
      const x = Math.round(X(m.t)), colour = m.kind === "fault_injected" ? FAULT_RGB : CLEARED_RGB;
      ctx.strokeStyle = colour; ctx.beginPath(); ctx.moveTo(x, top); ctx.lineTo(x, top + height); ctx.stroke();
      if (m.kind === "fault_injected") { ctx.fillStyle = colour; ctx.fillText(m.name, x + 4, top + height - 4); }
    }
    ctx.restore();
  }
  function timelineRange() {
    const st = S.store;
    if (!st.n) return null;
    const t0 = st.t(0), t1 = S.live ? Math.max(S.meta.duration_s, st.t(st.n - 1)) : st.t(st.n - 1);
    return [t0, Math.max(t1, t0 + 1e-6)];
  }
  function drawTimeline() {
    const cv = $("timeline"), ctx = cv.getContext("2d"), W = cv.width, H = cv.height, range = timelineRange();
    ctx.fillStyle = "#0b0f14"; ctx.fillRect(0, 0, W, H);
    S.timeline = null;
    if (!range) return;
    const [t0, t1] = range, L = 4, X = (t) => L + (t - t0) / (t1 - t0) * (W - 2 * L), now = S.store.t(S.store.n - 1);
    ctx.fillStyle = "#1b222c"; ctx.fillRect(L, 3, X(now) - L, H - 6);  // what has been recorded so far
    const rows = 3, rh = (H - 6) / rows;
    ctx.font = "10px system-ui";
    S.faults.forEach((f, k) => {  // a bar from injection to clearing (or now)
      if (f.injected_s === null) return;
      const end = f.active || f.cleared_s === null ? now : f.cleared_s, y = 3 + (k % rows) * rh;
      const x0 = X(f.injected_s), w = Math.max(2, X(end) - x0);
      ctx.fillStyle = f.active ? "rgba(255,120,0,0.5)" : "rgba(0,200,200,0.35)";
      ctx.fillRect(x0, y + 1, w, rh - 2);
      if (w > 60) { ctx.fillStyle = "#e6edf3"; ctx.fillText(f.name, x0 + 5, y + rh - 2); }
    });
    for (const m of S.faultMarks) { ctx.fillStyle = m.kind === "fault_injected" ? FAULT_RGB : CLEARED_RGB; ctx.fillRect(Math.round(X(m.t)) - 1, 0, 2, H); }
    ctx.fillStyle = "#f0f6fc"; ctx.fillRect(Math.round(X(S.t)), 0, 1, H);  // the time shown
    S.timeline = { t0, t1, x: X };
  }
  function drawFaultList() {
    const box = $("fault-list"), canAct = S.live && (S.status === "running" || S.status === "paused");
    box.textContent = "";
    for (const f of S.faults.slice().reverse()) {
      const div = document.createElement("div"), name = document.createElement("span"), when = document.createElement("span");
      div.className = f.active ? "on" : "off";
      name.className = "name"; name.textContent = f.name;
      const span = (f.injected_s !== null ? `t = ${f.injected_s.toFixed(1)}` : "t = ?") + (f.active ? " s, active" : f.cleared_s !== null ? `–${f.cleared_s.toFixed(1)} s` : " s, cleared");
      const params = Object.entries(f.params).map(([k, v]) => `${k}=${JSON.stringify(v)}`).join(", ");
      when.className = "when"; when.textContent = `${f.type} on ${f.device}, ${span}${params ? " (" + params + ")" : ""}`;
      div.title = when.textContent;
      div.append(name, when);
      if (f.active && canAct) {
        const btn = document.createElement("button");
        btn.textContent = "Clear"; btn.dataset.fault = f.name;
        btn.addEventListener("click", (ev) => { ev.stopPropagation(); faultRequest({ action: "clear", name: f.name }); });
        div.appendChild(btn);
      }
      if (f.injected_s !== null) div.addEventListener("click", () => seek(f.injected_s));
      box.appendChild(div);
    }
    for (const f of S.meta.faults || []) {  // the scenario's own, until they happen
      if (S.faults.some((x) => x.name === f.name)) continue;
      const div = document.createElement("div"), when = document.createElement("span");
      div.className = "scheduled"; when.className = "when"; when.textContent = `scheduled: ${f.when}`;
      div.appendChild(when); box.appendChild(div);
    }
    $("faults-panel").hidden = !S.live && !S.faults.length;
    document.querySelector("main").classList.toggle("with-faults", !$("faults-panel").hidden);
  }
  // "k=v, k=[1, 2, 3]; k=text": a value is read as JSON, else taken as text; commas inside brackets stay with it.
  function parseParams(text) {
    const parts = [];
    let depth = 0, quoted = false, cur = "";
    for (const ch of text) {
      if (ch === '"') quoted = !quoted;
      else if (!quoted && (ch === "[" || ch === "{")) depth++;
      else if (!quoted && (ch === "]" || ch === "}")) depth--;
      if (!quoted && depth === 0 && (ch === "," || ch === ";")) { parts.push(cur); cur = ""; continue; }
      cur += ch;
    }
    parts.push(cur);
    const out = {};
    for (const p of parts.map((x) => x.trim()).filter(Boolean)) {
      const i = p.indexOf("=");
      if (i <= 0) throw new Error(`parameter "${p}" is not allowed: name=value, e.g. rate=0.5`);
      const v = p.slice(i + 1).trim();
      let value;
      try { value = JSON.parse(v); } catch (e) { value = v; }
      out[p.slice(0, i).trim()] = value;
    }
    return out;
  }
  function faultTable() {  // the [[faults]] table the form describes
    const type = $("fault-type").value, known = S.faultTypes.find((t) => t.name === type);
    const table = { [known && known.tap === "link" ? "link" : "device"]: $("fault-device").value, type };
    Object.assign(table, parseParams($("fault-params").value));
    const dur = $("fault-duration").value.trim(), name = $("fault-name").value.trim();
    if (dur !== "") table.duration_s = +dur;
    if (name) table.name = name;
    return table;
  }
  async function faultRequest(body) {
    const headers = { "Content-Type": "application/json" };
    if (S.meta.token_required) headers["X-Stand-Token"] = $("token").value;
    const msg = $("fault-msg");
    msg.className = ""; msg.textContent = body.action === "inject" ? "injecting…" : "clearing…";
    let status = 0, answer = {};
    try {
      const r = await fetch("/api/faults", { method: "POST", headers, body: JSON.stringify(body) });
      status = r.status;
      answer = await r.json();
    } catch (err) { answer = { error: String(err) }; }
    const ok = status === 200;
    msg.className = ok ? "ok" : "error";
    msg.textContent = ok ? `${body.action === "inject" ? "injected" : "cleared"} ${answer.name} (from the run's next tick)` : (answer.error || `HTTP ${status}`);
    S.faultAnswers.push({ status, ...answer });
    return { status, body: answer };
  }
  function fillFaultTypes() {
    const dev = S.meta.devices.find((d) => d.name === $("fault-device").value), taps = dev && dev.fault_taps;
    const sel = $("fault-type"), was = sel.value;
    const types = S.faultTypes.filter((t) => !taps || t.tap in taps);  // a view.json without taps: every type
    sel.textContent = "";
    for (const t of types) {
      const o = document.createElement("option");
      o.value = o.textContent = t.name; o.title = t.text;
      sel.appendChild(o);
    }
    if (types.some((t) => t.name === was)) sel.value = was;
    showFaultParams();
  }
  function showFaultParams() {
    // A parameter's key may hold {unit}: the device's measurement unit (rad_s gives bias_rad_s).
    const t = S.faultTypes.find((x) => x.name === $("fault-type").value);
    const dev = S.meta.devices.find((d) => d.name === $("fault-device").value);
    const unit = dev && dev.fault_taps && dev.fault_taps.measurement ? dev.fault_taps.measurement.unit : "{unit}";
    const params = t ? t.params.filter((p) => p.default === null) : [];  // the ones without a default first
    $("fault-params").placeholder = params.length ? params.map((p) => `${p.key.replace("{unit}", unit)}=…`).join(", ") : "name=value, ...";
    $("fault-params").title = t ? t.params.map((p) => `${p.key.replace("{unit}", unit)}: ${p.text}` + (p.default !== null ? ` (default ${JSON.stringify(p.default)})` : "")).join("\n") : "";
    $("fault-type").title = t ? t.text : "";
  }
  async function setupFaults() {
    $("fault-form").hidden = !S.live;
    if (!S.live) return;
    try { S.faultTypes = (await getJSON("/api/faults")).types || []; } catch (err) { S.faultTypes = []; }
    const dev = $("fault-device");
    for (const d of S.meta.devices) { const o = document.createElement("option"); o.value = o.textContent = d.name; dev.appendChild(o); }
    dev.addEventListener("change", fillFaultTypes);
    $("fault-type").addEventListener("change", showFaultParams);
    fillFaultTypes();
    $("fault-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      let table;
      try { table = faultTable(); } catch (err) { $("fault-msg").className = "error"; $("fault-msg").textContent = err.message; return; }
      faultRequest({ action: "inject", fault: table });
    });
  }

  // ------------------------------------------------------------------------------------------ tracker images
  // The newest detector frame of each image-source tracker (stand/view/frames.py): the server announces a frame on
  // the websocket, the page loads it from /api/frame (one load at a time per tracker: a frame that arrives while
  // one loads waits, and only the newest of those is loaded). Its solution's validity and flags are the tracker's
  // telemetry at the exposure plus the tracker's output delay (and one recording period).
  function setupTrackerImages() {
    const devs = S.meta.devices.filter((d) => d.image);
    S.imageDevices = devs;
    $("trackimg").hidden = devs.length === 0;
    // Frames to show: the panel beside the faults; only "no image" lines: one thin row above the plots.
    const frames = S.live && devs.some((d) => d.image.renders);
    document.querySelector("main").classList.toggle("with-images", frames);
    document.querySelector("main").classList.toggle("image-notes", devs.length > 0 && !frames);
    $("trackimg-title").textContent = frames ? "tracker image (live, the newest frame)" : "tracker image:";
    const list = $("trackimg-list");
    for (const d of devs) {
      const fig = document.createElement("figure"), cap = document.createElement("figcaption");
      fig.dataset.device = d.name;
      if (d.image.renders && S.live) {
        const img = document.createElement("img");
        img.alt = `${d.name}: detector image`; img.hidden = true;
        img.addEventListener("load", () => frameLoaded(d.name));
        img.addEventListener("error", () => frameLoaded(d.name, true));
        fig.appendChild(img);
        cap.textContent = `${d.name}: waiting for the first frame`;
      } else if (d.image.renders) cap.textContent = `${d.name}: no image in a replay (frames are shown live only)`;
      else cap.textContent = `${d.name}: no image: ${d.image.why || "this tracker does not render"}`;
      fig.appendChild(cap); list.appendChild(fig);
      S.frames[d.name] = { shown: null, loading: null, waiting: null, loaded: 0, errors: 0 };
    }
  }
  function onFrame(msg) {
    const f = S.frames[msg.device];
    if (!f) return;
    if (f.loading) { f.waiting = msg; return; }
    loadFrame(msg.device, msg);
  }
  function loadFrame(name, msg) {
    const f = S.frames[name], img = document.querySelector(`#trackimg figure[data-device="${name}"] img`);
    if (!img) return;
    f.loading = msg;
    img.src = `/api/frame?device=${encodeURIComponent(name)}&seq=${msg.seq}`;
  }
  function frameLoaded(name, failed) {
    const f = S.frames[name], img = document.querySelector(`#trackimg figure[data-device="${name}"] img`);
    if (failed) f.errors++;
    else { f.shown = f.loading; f.loaded++; img.hidden = false; }
    f.loading = null;
    drawTrackerImages();
    if (f.waiting) { const next = f.waiting; f.waiting = null; loadFrame(name, next); }
  }
  function drawTrackerImages() {
    for (const d of S.imageDevices || []) {
      const f = S.frames[d.name];
      if (!f || !f.shown) continue;
      const m = f.shown, cap = document.querySelector(`#trackimg figure[data-device="${d.name}"] figcaption`);
      const stars = m.stars_extracted === null || m.stars_extracted === undefined ? "–" : m.stars_extracted;
      const at = m.t_s + (d.image.delay_s || 0) + 1 / (S.meta.record_rate_hz || 10);
      const st = S.store, k = st.n && st.t(st.n - 1) >= at - 1e-9 ? st.index(at) : -1;
      let sol = "solution pending";
      if (k >= 0) {
        const s = deviceState(d, k), flags = st.get(d.name + ".flags", k);
        sol = `solution ${s.label || "–"}` + (Number.isFinite(flags) ? `, flags 0x${(flags | 0).toString(16).padStart(2, "0")}` : "");
      }
      cap.textContent = `${d.name} at t = ${m.t_s.toFixed(1)} s: ${stars} stars extracted, ${m.stars_matched} matched; ${sol}`;
      cap.title = `exposure at t = ${m.t_s.toFixed(3)} s, ${m.full_px[0]} x ${m.full_px[1]} px shown at ${m.size_px[0]} x ${m.size_px[1]} (2 x 2 maximum, asinh stretch); the solution reported ${d.image.delay_s} s later`;
    }
  }

  // ------------------------------------------------------------------------------------------ time and drawing
  let pending = false;
  function redraw() {
    if (pending) return;
    pending = true;
    requestAnimationFrame(() => { pending = false; drawAll(); });
  }
  function drawAll() {
    const t0 = performance.now();
    S.i = S.store.index(S.t);
    if (S.i >= 0) S.t = Math.max(S.t, S.store.t(S.i));
    if (S.events.length !== S.eventsSeen || S.status !== S.statusSeen) eventsChanged();
    const parts = S.stats.parts = {};
    const timed = (name, fn) => { const a = performance.now(); fn(); parts[name] = +(performance.now() - a).toFixed(1); };
    timed("panorama", drawPanorama); timed("view3d", draw3d); timed("attitude", drawAttitude); timed("ground", drawGround);
    timed("plots", () => { for (const p of S.plots || []) p.draw(); if (S.strip) S.strip.draw(); });
    timed("events", () => drawEvents(false));
    timed("timeline", drawTimeline);
    timed("images", drawTrackerImages);
    header();
    const now = performance.now();
    S.stats.draws++; S.stats.lastDrawMs = now - t0;
    if (S.stats.firstDrawMs === null && S.i >= 0) S.stats.firstDrawMs = now;
    document.body.dataset.drawn = String(S.stats.draws);
  }
  function header() {
    const st = S.store;
    if (S.i < 0) return;
    const t = st.t(S.i), epoch = Date.parse(S.meta.epoch);
    $("utc").textContent = "UTC " + new Date(epoch + t * 1000).toISOString().replace("T", " ").slice(0, 21);
    $("tsim").textContent = `t = ${t.toFixed(1)} s of ${S.meta.duration_s.toFixed(0)} s`;
    const t0 = st.t(0), t1 = S.live ? S.meta.duration_s : st.t(st.n - 1);
    const slider = $("slider");
    if (!slider.matches(":active")) slider.value = String(Math.round((t - t0) / Math.max(t1 - t0, 1e-9) * 1000));
    const mode = st.has("adcs_mode") ? st.get("adcs_mode", S.i) : null;
    $("adcs-mode").hidden = mode === null;
    if (mode !== null) $("adcs-mode").textContent = Number.isFinite(mode) ? `ADCS mode ${mode}${S.modeNames.has(mode) ? " " + S.modeNames.get(mode) : ""}` : "ADCS mode –";
    $("status").textContent = S.status;
    $("status").className = "badge " + S.status;
    $("pause").disabled = !S.live || S.status !== "running";
    $("resume").disabled = !S.live || S.status !== "paused";
    $("stop").disabled = !S.live || !(S.status === "running" || S.status === "paused");
    $("fault-inject").disabled = $("stop").disabled;
  }
  function seek(t) {
    if (!S.store.n) return;
    S.t = Math.max(S.store.t(0), Math.min(t, S.store.t(S.store.n - 1)));
    if (S.live) { S.follow = S.t >= S.store.t(S.store.n - 1) - 1e-6; $("follow").checked = S.follow; }
    redraw();
  }
  let lastFrame = null;
  function tick(now) {
    if (S.playing && S.store.n) {
      if (lastFrame !== null) {
        const end = S.store.t(S.store.n - 1);
        S.t = Math.min(end, S.t + (now - lastFrame) / 1000 * parseFloat($("speed").value));
        if (S.t >= end && !S.live) { S.playing = false; $("play").textContent = "▶"; }
        drawAll();
      }
      lastFrame = now;
    } else lastFrame = null;
    requestAnimationFrame(tick);
  }

  // ------------------------------------------------------------------------------------------ loading
  async function getJSON(url) {
    const r = await fetch(url);
    if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
    return r.json();
  }
  async function loadStars() {
    const tab = await getJSON("/api/stars?mag=9"), c = Store.decode(tab.stars), n = c.n;
    const u = new Float32Array(3 * n), mag = new Float32Array(n);
    for (let k = 0; k < n; k++) {
      const ra = c.data[3 * k], dec = c.data[3 * k + 1];
      u[3 * k] = Math.cos(dec) * Math.cos(ra); u[3 * k + 1] = Math.cos(dec) * Math.sin(ra); u[3 * k + 2] = Math.sin(dec); mag[k] = c.data[3 * k + 2];
    }
    S.stars = { count: n, u, mag };
  }
  function onSamples(msg) {
    const added = S.store.append(msg.samples || {});
    if (msg.events) S.events.push(...msg.events);
    if (msg.status) S.status = msg.status;
    if (added) {
      if (!S.plotsHaveData) buildPlots();  // the columns are known only once samples arrive
      S.stats.pushes++; S.stats.pushTimes.push(performance.now());
      if (S.stats.pushTimes.length > 50) S.stats.pushTimes.shift();
      if (S.follow) S.t = S.store.t(S.store.n - 1);
    }
    liveRedraw();
  }
  // A live run pushes ten times a second; the page redraws at most LIVE_FPS times, which is what an operator
  // can follow and leaves the machine's cores to the run.
  const LIVE_FPS = 5;
  let liveTimer = null, lastLive = 0;
  function liveRedraw() {
    if (liveTimer !== null) return;
    const wait = Math.max(0, lastLive + 1000 / LIVE_FPS - performance.now());
    liveTimer = setTimeout(() => { liveTimer = null; lastLive = performance.now(); redraw(); }, wait);
  }
  function connect() {
    const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
    ws.onmessage = (ev) => {
      const msg = JSON.parse(ev.data);
      if (msg.type === "samples") onSamples(msg);
      else if (msg.type === "events") { S.events.push(...msg.events); redraw(); }
      else if (msg.type === "status") { S.status = msg.status; if (msg.events) S.events.push(...msg.events); redraw(); }
      else if (msg.type === "summary") refreshVerdict();
      else if (msg.type === "frame") onFrame(msg);
      else if (msg.type === "error") console.warn(msg.message);
    };
    ws.onclose = () => { if (S.live && S.status !== "finished") { S.status = "disconnected"; redraw(); } };
    S.ws = ws;
  }
  async function refreshVerdict() {  // the finished run's summary is written: its verdict, as a replay shows it
    try { S.meta.summary = (await getJSON("/api/meta")).summary; } catch (err) { return; }
    drawVerdict();
  }
  async function control(command) {
    const headers = { "Content-Type": "application/json" };
    if (S.meta.token_required) headers["X-Stand-Token"] = $("token").value;
    const r = await fetch("/api/control", { method: "POST", headers, body: JSON.stringify({ command }) });
    const body = await r.json();
    if (!r.ok) { alert(body.error || `HTTP ${r.status}`); return; }
    S.status = body.status; redraw();
  }

  async function main() {
    pano.canvas = $("pano"); pano.ctx = pano.canvas.getContext("2d");
    $("euler-seq").innerHTML = EULER_SEQS.map((s) => `<option ${s === "321" ? "selected" : ""}>${s}</option>`).join("");
    S.meta = await getJSON("/api/meta");
    S.live = S.meta.mode === "live"; S.status = S.meta.status;
    // "the mode (0 detumble, 1 Sun acquisition, 2 fine pointing)": the names of the controller's modes
    S.modeNames = new Map([...(S.meta.mode_meaning || "").matchAll(/(?:\(|, )(\d+) ([^,)]+)/g)].map((m) => [+m[1], m[2]]));
    $("scenario").textContent = S.meta.scenario;
    $("mode").textContent = S.live ? "LIVE" : "REPLAY"; $("mode").className = "badge " + (S.live ? "live" : "");
    $("status").hidden = !S.live;
    $("control").hidden = !S.live; $("token").hidden = !S.meta.token_required;
    $("follow").parentElement.hidden = !S.live;
    const [samples] = await Promise.all([getJSON("/api/samples"), loadStars(),
      getJSON("/assets/land-110m.json").then((d) => { S.land = d.rings; })]);
    S.store.append(samples.samples || {});
    S.events = samples.events || []; if (samples.status) S.status = samples.status;
    S.t = S.live && S.store.n ? S.store.t(S.store.n - 1) : (S.store.n ? S.store.t(0) : 0);
    buildPlots();
    setupTrackerImages();
    if (S.live) connect();
    const legend = [["Sun", COLORS.sun], ["Moon", COLORS.moon], ["body +X", COLORS.axes[0]], ["+Y", COLORS.axes[1]], ["+Z", COLORS.axes[2]],
      ["valid field", COLORS.valid], ["Sun in field", COLORS.sunFlag], ["Moon", COLORS.moonFlag], ["Earth", COLORS.earthFlag], ["rate", COLORS.rate], ["no solution", COLORS.nosol]];
    // Built node by node: the page's content policy allows no inline style attributes.
    for (const [k, c] of legend) {
      const span = document.createElement("span"), dotEl = document.createElement("i");
      dotEl.style.background = c; span.appendChild(dotEl); span.appendChild(document.createTextNode(k));
      $("pano-legend").appendChild(span);
    }
    const note = document.createElement("span");
    note.textContent = "filled square: + body axis, hollow: − axis; circled crosses: velocity, nadir, magnetic field B";
    $("pano-legend").appendChild(note);
    setupLook();
    setup3d();
    await setupFaults();
    $("timeline").addEventListener("click", (ev) => {
      if (!S.timeline) return;
      const cv = $("timeline"), rect = cv.getBoundingClientRect(), x = (ev.clientX - rect.left) / rect.width * cv.width;
      seek(S.timeline.t0 + (x - 4) / (cv.width - 8) * (S.timeline.t1 - S.timeline.t0));
    });
    for (const id of ["pano-frame", "pano-proj", "true-size", "show-exclusion", "show-heads", "att-frame", "euler-seq"]) $(id).addEventListener("change", redraw);
    $("mag").addEventListener("input", () => { $("mag-value").textContent = $("mag").value; redraw(); });
    $("slider").addEventListener("input", () => {
      if (!S.store.n) return;
      const t0 = S.store.t(0), t1 = S.live ? S.meta.duration_s : S.store.t(S.store.n - 1);
      seek(t0 + (+$("slider").value) / 1000 * (t1 - t0));
    });
    $("play").addEventListener("click", () => { S.playing = !S.playing; $("play").textContent = S.playing ? "❚❚" : "▶"; if (S.playing && S.live) { S.follow = false; $("follow").checked = false; } });
    $("follow").addEventListener("change", () => { S.follow = $("follow").checked; if (S.follow) seek(Infinity); });
    $("pause").addEventListener("click", () => control("pause"));
    $("resume").addEventListener("click", () => control("resume"));
    $("stop").addEventListener("click", () => { if (confirm("Stop the run? The summary and the telemetry so far are kept.")) control("stop"); });
    document.addEventListener("keydown", (ev) => { if (ev.key === " " && ev.target === document.body) { ev.preventDefault(); $("play").click(); } });
    drawAll();
    drawEvents(true);
    drawVerdict();
    requestAnimationFrame(tick);
  }
  S.lookYaw = 0; S.lookPitch = 0; S.lookFov = 120;
  function setupLook() {
    const sel = $("look-at"), opts = [];
    for (const d of S.meta.devices) if (d.fovs.length && !d.fovs[0].head) opts.push([`dev:${d.name}`, `${d.name} boresight`]);
    opts.push(["axis:0+", "body +X"], ["axis:1+", "body +Y"], ["axis:2+", "body +Z"], ["axis:2-", "body −Z"],
      ["nadir", "nadir"], ["zenith", "zenith"], ["velocity", "velocity"], ["sun", "Sun"]);
    sel.innerHTML = opts.map(([v, t]) => `<option value="${v}">${t}</option>`).join("");
    sel.addEventListener("change", () => { S.lookYaw = S.lookPitch = 0; redraw(); });
    $("look-fov").addEventListener("input", () => { S.lookFov = +$("look-fov").value; redraw(); });
    let drag = null;
    const cv = pano.canvas;
    cv.addEventListener("pointerdown", (ev) => { if ($("pano-proj").value === "inside") { drag = [ev.clientX, ev.clientY, S.lookYaw, S.lookPitch]; cv.setPointerCapture(ev.pointerId); } });
    cv.addEventListener("pointermove", (ev) => {
      if (!drag) return;
      const k = S.lookFov / cv.getBoundingClientRect().width;
      S.lookYaw = drag[2] - (ev.clientX - drag[0]) * k; S.lookPitch = Math.max(-89, Math.min(89, drag[3] + (ev.clientY - drag[1]) * k));
      redraw();
    });
    cv.addEventListener("pointerup", () => { drag = null; });
  }
  S.seek = seek; S.project = (u, kind, W, H) => proj[kind].fwd(u, W, H); S.eulerFromDcm = eulerFromDcm; S.quatFromDcm = quatFromDcm;
  S.control = control;
  S.faultRequest = faultRequest; S.parseParams = parseParams;
  S.ready = main().then(() => { S.loaded = true; }).catch((err) => { console.error(err); S.loadError = String(err); });
})();
