// socdiff viewer: plays multi-person skeleton motion embedded in this page, with a small
// canvas-2D perspective renderer (no libraries, no network). Data layout: see
// engine/src/export/html.rs.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const body = document.body;
  const canvas = $("view");
  const ctx = canvas.getContext("2d");
  const BG = [246, 247, 249], BG_FORECAST = [255, 246, 234];
  const OBSERVED = "#5b8def", FORECAST = "#f0a030";
  const FOV = (45 * Math.PI) / 180, NEAR = 0.05;
  let meta = null;
  let scenes = [];
  const st = {
    scene: 0, sample: "all", frame: 0, fpos: 0, playing: false, speed: 1,
    signals: true, ids: false, cam: null, last: 0, timer: 0, raf: 0, drawPending: false, dpr: 1,
  };

  function fail(msg) {
    $("message").textContent = msg;
    $("message").hidden = false;
    body.dataset.error = msg;
  }

  // ---- data --------------------------------------------------------------------------------

  async function inflate(b64) {
    const bin = atob(b64.trim());
    const bytes = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
    if (typeof DecompressionStream === "undefined") {
      throw new Error("this browser cannot decompress the embedded data (no DecompressionStream); use a current Chrome, Edge, Firefox or Safari");
    }
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream("deflate"));
    return new Uint8Array(await new Response(stream).arrayBuffer());
  }

  function decodeScene(m, buf) {
    const P = m.persons.length, J = m.joints.length, F = m.frames, S = P * J * 3;
    const sc = Object.assign({}, m, { P: P, J: J, F: F, S: S, samples: [] });
    for (const sm of m.samples) {
      const pos = new Int16Array(F * S);
      if (sm.start > 0) pos.set(sc.samples[0].pos.subarray(0, sm.start * S));
      const base = sm.start * S;
      pos.set(new Int16Array(buf.buffer, buf.byteOffset + sm.pos, F * S - base), base);
      for (let i = base + S; i < F * S; i++) pos[i] += pos[i - S]; // Int16Array wraps like i16
      sc.samples.push({
        label: sm.label,
        pos: pos,
        valid: sm.valid == null ? null : new Uint8Array(buf.buffer, buf.byteOffset + sm.valid, F * P),
        signals: sm.signals.map((g) => ({
          name: g.name, binary: g.binary,
          values: new Float32Array(buf.buffer.slice(buf.byteOffset + g.offset, buf.byteOffset + g.offset + 4 * F * P)),
        })),
      });
    }
    return sc;
  }

  // ---- camera ------------------------------------------------------------------------------

  function resetCamera() {
    const sc = scenes[st.scene];
    st.cam = {
      target: sc.center.slice(),
      az: -Math.PI / 2 + 0.55,
      el: 0.42,
      dist: Math.max(2, (sc.radius / Math.tan(FOV / 2)) * 0.95),
    };
  }

  function projector(rect) {
    const c = st.cam;
    const d = [Math.cos(c.el) * Math.cos(c.az), Math.cos(c.el) * Math.sin(c.az), Math.sin(c.el)];
    const eye = [c.target[0] + c.dist * d[0], c.target[1] + c.dist * d[1], c.target[2] + c.dist * d[2]];
    const fwd = [-d[0], -d[1], -d[2]];
    let right = [fwd[1], -fwd[0], 0];
    const rn = Math.hypot(right[0], right[1]) || 1;
    right = [right[0] / rn, right[1] / rn, 0];
    const up = [right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2], right[0] * fwd[1] - right[1] * fwd[0]];
    const f = (0.5 * Math.min(rect.w, rect.h)) / Math.tan(FOV / 2);
    return {
      cx: rect.x + rect.w / 2, cy: rect.y + rect.h / 2, f: f,
      // camera space: [right, up, depth]
      cam(x, y, z) {
        const vx = x - eye[0], vy = y - eye[1], vz = z - eye[2];
        return [vx * right[0] + vy * right[1] + vz * right[2], vx * up[0] + vy * up[1] + vz * up[2], vx * fwd[0] + vy * fwd[1] + vz * fwd[2]];
      },
      screen(p) {
        return [this.cx + (this.f * p[0]) / p[2], this.cy - (this.f * p[1]) / p[2]];
      },
      // A segment clipped to the near plane, in screen space, or null.
      segment(a, b) {
        if (a[2] < NEAR && b[2] < NEAR) return null;
        if (a[2] < NEAR || b[2] < NEAR) {
          const t = (NEAR - a[2]) / (b[2] - a[2]);
          const m = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), NEAR];
          if (a[2] < NEAR) a = m; else b = m;
        }
        return [this.screen(a), this.screen(b)];
      },
    };
  }

  // ---- drawing -----------------------------------------------------------------------------

  function panels() {
    const sc = scenes[st.scene];
    const idx = st.sample === "all" ? sc.samples.map((_, i) => i) : [Number(st.sample)];
    const W = canvas.width, H = canvas.height, n = idx.length;
    let best = 1, bestScore = -1;
    for (let cols = 1; cols <= n; cols++) {
      const rows = Math.ceil(n / cols);
      const w = W / cols, h = H / rows;
      // Large square-ish panels, few empty cells.
      const score = Math.min(w, h) * (1 - 0.08 * (cols * rows - n) - 0.02 * Math.abs(w / h - 1.2));
      if (score > bestScore) { bestScore = score; best = cols; }
    }
    const cols = best, rows = Math.ceil(n / cols);
    const w = W / cols, h = H / rows;
    return idx.map((s, i) => ({ sample: s, x: (i % cols) * w, y: Math.floor(i / cols) * h, w: w, h: h }));
  }

  function rgb(c, a) { return "rgba(" + c[0] + "," + c[1] + "," + c[2] + "," + a + ")"; }

  function drawPanel(sc, rect) {
    const smp = sc.samples[rect.sample];
    const f = st.frame, dpr = st.dpr;
    const forecast = f >= sc.observed;
    const pr = projector(rect);
    ctx.save();
    ctx.beginPath();
    ctx.rect(rect.x, rect.y, rect.w, rect.h);
    ctx.clip();
    ctx.fillStyle = rgb(forecast ? BG_FORECAST : BG, 1);
    ctx.fillRect(rect.x, rect.y, rect.w, rect.h);

    // Floor grid (0.5 m).
    const c = sc.center, R = Math.ceil(sc.radius + 1), z0 = sc.floor;
    ctx.strokeStyle = "rgba(120,128,140,0.28)";
    ctx.lineWidth = dpr;
    ctx.beginPath();
    for (let i = -2 * R; i <= 2 * R; i++) {
      const gx = Math.round(c[0] * 2) / 2 + i / 2, gy = Math.round(c[1] * 2) / 2 + i / 2;
      for (const seg of [
        pr.segment(pr.cam(gx, c[1] - R, z0), pr.cam(gx, c[1] + R, z0)),
        pr.segment(pr.cam(c[0] - R, gy, z0), pr.cam(c[0] + R, gy, z0)),
      ]) {
        if (seg) { ctx.moveTo(seg[0][0], seg[0][1]); ctx.lineTo(seg[1][0], seg[1][1]); }
      }
    }
    ctx.stroke();

    // Joints in camera space.
    const P = sc.P, J = sc.J, base = f * sc.S, o = sc.origin, q = sc.step;
    const pts = new Array(P * J), world = new Array(P * J);
    for (let p = 0; p < P; p++) {
      for (let j = 0; j < J; j++) {
        const i = base + (p * J + j) * 3;
        const x = o[0] + q * smp.pos[i], y = o[1] + q * smp.pos[i + 1], z = o[2] + q * smp.pos[i + 2];
        world[p * J + j] = [x, y, z];
        pts[p * J + j] = pr.cam(x, y, z);
      }
    }
    // Shadows on the floor.
    ctx.strokeStyle = "rgba(60,70,90,0.13)";
    ctx.lineWidth = 4 * dpr;
    ctx.lineCap = "round";
    ctx.beginPath();
    for (let p = 0; p < P; p++) {
      for (const [a, b] of sc.bones) {
        const wa = world[p * J + a], wb = world[p * J + b];
        const seg = pr.segment(pr.cam(wa[0], wa[1], z0), pr.cam(wb[0], wb[1], z0));
        if (seg) { ctx.moveTo(seg[0][0], seg[0][1]); ctx.lineTo(seg[1][0], seg[1][1]); }
      }
    }
    ctx.stroke();
    // Persons far to near; each person's bones as one path, joints as one path.
    const order = [];
    for (let p = 0; p < P; p++) {
      let depth = 0;
      for (let j = 0; j < J; j++) depth += pts[p * J + j][2];
      order.push([depth, p]);
    }
    order.sort((u, v) => v[0] - u[0]);
    ctx.lineWidth = 3.2 * dpr;
    ctx.setLineDash(forecast ? [7 * dpr, 4 * dpr] : []);
    ctx.lineCap = forecast ? "butt" : "round";
    ctx.lineJoin = "round";
    for (const [, p] of order) {
      const valid = !smp.valid || smp.valid[f * P + p];
      const colour = valid ? sc.colours[p] : "rgba(150,150,150,0.45)";
      ctx.strokeStyle = colour;
      ctx.beginPath();
      for (const [a, b] of sc.bones) {
        const seg = pr.segment(pts[p * J + a], pts[p * J + b]);
        if (seg) { ctx.moveTo(seg[0][0], seg[0][1]); ctx.lineTo(seg[1][0], seg[1][1]); }
      }
      ctx.stroke();
      ctx.fillStyle = colour;
      ctx.beginPath();
      for (let j = 0; j < J; j++) {
        const c3 = pts[p * J + j];
        if (c3[2] < NEAR) continue;
        const s = pr.screen(c3);
        ctx.moveTo(s[0] + 2.6 * dpr, s[1]);
        ctx.arc(s[0], s[1], 2.6 * dpr, 0, 2 * Math.PI);
      }
      ctx.setLineDash([]);
      ctx.fill();
      ctx.setLineDash(forecast ? [7 * dpr, 4 * dpr] : []);
    }
    ctx.setLineDash([]);
    // Labels above heads: ids and active signals.
    ctx.font = "600 " + 12 * dpr + "px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "bottom";
    ctx.lineJoin = "round";
    for (let p = 0; p < P; p++) {
      const words = [];
      if (st.ids) {
        const who = sc.persons[p];
        words.push(who.role ? who.id + " (" + who.role + ")" : String(who.id));
      }
      if (st.signals) {
        for (const g of smp.signals) {
          const v = g.values[f * P + p];
          if (g.binary) { if (v >= 0.5) words.push(g.name); } else words.push(g.name + " " + v.toFixed(2));
        }
      }
      if (!words.length) continue;
      let top = 0;
      for (let j = 1; j < J; j++) if (world[p * J + j][2] > world[p * J + top][2]) top = j;
      const w = world[p * J + top];
      const c3 = pr.cam(w[0], w[1], w[2] + 0.12);
      if (c3[2] < NEAR) continue;
      const s = pr.screen(c3);
      const text = words.join(" · ");
      ctx.lineWidth = 4 * dpr;
      ctx.strokeStyle = "rgba(255,255,255,0.92)";
      ctx.strokeText(text, s[0], s[1]);
      ctx.fillStyle = sc.colours[p];
      ctx.fillText(text, s[0], s[1]);
    }
    // Caption: sample label and phase.
    ctx.textAlign = "left";
    ctx.textBaseline = "top";
    ctx.font = 12 * dpr + "px system-ui, sans-serif";
    let x = rect.x + 8 * dpr;
    const y = rect.y + 7 * dpr;
    if (sc.samples.length > 1) {
      ctx.fillStyle = "#1d2330";
      ctx.fillText(smp.label, x, y + 2 * dpr);
      x += ctx.measureText(smp.label).width + 8 * dpr;
    }
    const phase = forecast ? "forecast +" + ((f - sc.observed + 1) / sc.fps).toFixed(2) + " s" : "observed";
    const tw = ctx.measureText(phase).width + 12 * dpr;
    ctx.fillStyle = forecast ? FORECAST : OBSERVED;
    ctx.fillRect(x, y, tw, 18 * dpr);
    ctx.fillStyle = "#ffffff";
    ctx.fillText(phase, x + 6 * dpr, y + 2 * dpr);
    ctx.restore();
    // Panel border.
    ctx.strokeStyle = "#c9ced6";
    ctx.lineWidth = dpr;
    ctx.strokeRect(rect.x + 0.5, rect.y + 0.5, rect.w - 1, rect.h - 1);
  }

  function draw() {
    st.drawPending = false;
    if (!scenes.length) return;
    const sc = scenes[st.scene];
    ctx.fillStyle = rgb(BG, 1);
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    for (const rect of panels()) drawPanel(sc, rect);
  }

  function requestDraw() {
    if (st.drawPending) return;
    st.drawPending = true;
    requestAnimationFrame(draw);
    setTimeout(() => { if (st.drawPending) draw(); }, 50);
  }

  // Sampled pixel counts, for automated checks: all non-background pixels, and per panel the
  // saturated (skeleton-coloured) pixels below the caption.
  function pixelCounts() {
    const W = canvas.width, H = canvas.height;
    if (!W || !H) return;
    const img = ctx.getImageData(0, 0, W, H).data;
    const near = (i, c) => Math.abs(img[i] - c[0]) + Math.abs(img[i + 1] - c[1]) + Math.abs(img[i + 2] - c[2]) < 6;
    let painted = 0;
    for (let i = 0; i < img.length; i += 12) if (!near(i, BG) && !near(i, BG_FORECAST)) painted++;
    const perPanel = panels().map((r) => {
      let n = 0;
      for (let y = Math.floor(r.y + 30 * st.dpr); y < r.y + r.h - 2; y += 2) {
        for (let x = Math.floor(r.x + 2); x < r.x + r.w - 2; x += 2) {
          const i = (y * W + x) * 4;
          if (Math.max(img[i], img[i + 1], img[i + 2]) - Math.min(img[i], img[i + 1], img[i + 2]) > 70) n++;
        }
      }
      return n;
    });
    body.dataset.painted = String(painted);
    body.dataset.panelColoured = perPanel.join(",");
  }

  // ---- state -------------------------------------------------------------------------------

  function setFrame(f, fromPlayback) {
    const sc = scenes[st.scene];
    f = Math.max(0, Math.min(sc.F - 1, f | 0));
    st.frame = f;
    if (!fromPlayback) st.fpos = f;
    $("slider").value = String(f);
    $("counter").textContent = "frame " + f + " / " + (sc.F - 1) + " · " + (f / sc.fps).toFixed(2) + " s";
    const forecast = f >= sc.observed;
    const phase = $("phase");
    phase.textContent = forecast ? "forecast" : "observed";
    phase.className = forecast ? "forecast" : "observed";
    body.dataset.frame = String(f);
    document.title = meta.title + " · frame " + f;
    if (!fromPlayback) requestDraw();
  }

  function tick() {
    clearTimeout(st.timer);
    cancelAnimationFrame(st.raf);
    if (!st.playing) return;
    const now = performance.now();
    const dt = Math.min(0.25, Math.max(0, (now - st.last) / 1000));
    st.last = now;
    const sc = scenes[st.scene];
    st.fpos += dt * sc.fps * st.speed;
    if (st.fpos >= sc.F) st.fpos %= sc.F;
    setFrame(Math.floor(st.fpos), true);
    draw();
    // Animation frames when the page is shown; a timer keeps playing where they are throttled.
    st.raf = requestAnimationFrame(tick);
    st.timer = setTimeout(tick, 40);
  }

  function setPlaying(on) {
    st.playing = on;
    $("play").innerHTML = on ? "&#10074;&#10074;" : "&#9654;";
    body.dataset.playing = on ? "1" : "0";
    if (on) {
      st.last = performance.now();
      st.fpos = st.frame;
      tick();
    } else {
      clearTimeout(st.timer);
      cancelAnimationFrame(st.raf);
    }
  }

  function selectScene(i) {
    st.scene = i;
    const sc = scenes[i];
    const sel = $("sample");
    sel.innerHTML = "";
    if (sc.samples.length > 1) {
      sel.add(new Option("all " + sc.samples.length + " side by side", "all"));
      sc.samples.forEach((s, k) => sel.add(new Option(s.label, String(k))));
    }
    if (st.sample !== "all" && Number(st.sample) >= sc.samples.length) st.sample = "all";
    if (sc.samples.length === 1) st.sample = "0";
    sel.value = st.sample;
    $("sample-wrap").hidden = sc.samples.length < 2;
    const legend = $("legend");
    legend.innerHTML = "";
    sc.persons.forEach((p, k) => {
      const span = document.createElement("span");
      span.className = "person";
      const dot = document.createElement("span");
      dot.className = "swatch";
      dot.style.background = sc.colours[k];
      span.appendChild(dot);
      span.appendChild(document.createTextNode(p.role ? p.id + " (" + p.role + ")" : String(p.id)));
      legend.appendChild(span);
    });
    const slider = $("slider");
    slider.max = String(sc.F - 1);
    const obsFrac = sc.F > 1 ? Math.min(1, sc.observed / sc.F) : 1;
    $("track-observed").style.width = (100 * obsFrac).toFixed(3) + "%";
    $("signals-wrap").hidden = !sc.samples.some((s) => s.signals.length);
    body.dataset.samples = String(sc.samples.length);
    body.dataset.persons = String(sc.P);
    resetCamera();
    setFrame(Math.min(st.frame, sc.F - 1), false);
  }

  function resize() {
    const dpr = window.devicePixelRatio || 1;
    st.dpr = dpr;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    draw();
  }

  // ---- input -------------------------------------------------------------------------------

  function bindInput() {
    $("play").addEventListener("click", () => setPlaying(!st.playing));
    $("slider").addEventListener("input", (e) => setFrame(Number(e.target.value), false));
    $("speed").addEventListener("change", (e) => { st.speed = Number(e.target.value); });
    $("sample").addEventListener("change", (e) => { st.sample = e.target.value; requestDraw(); });
    $("scene").addEventListener("change", (e) => selectScene(Number(e.target.value)));
    $("signals").addEventListener("change", (e) => { st.signals = e.target.checked; requestDraw(); });
    $("ids").addEventListener("change", (e) => { st.ids = e.target.checked; requestDraw(); });
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => {
      drag = { x: e.clientX, y: e.clientY, pan: e.button !== 0 || e.shiftKey };
      canvas.setPointerCapture(e.pointerId);
    });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
      drag.x = e.clientX;
      drag.y = e.clientY;
      const c = st.cam;
      if (drag.pan) {
        const k = c.dist * 0.0016;
        const ca = Math.cos(c.az), sa = Math.sin(c.az);
        // The scene follows the pointer: screen right is (-sin az, cos az) on the floor, and
        // dragging down pulls the floor towards the eye (the target moves away, along -d).
        c.target[0] += dx * k * sa - dy * k * ca;
        c.target[1] += -dx * k * ca - dy * k * sa;
      } else {
        c.az -= dx * 0.008;
        c.el = Math.max(-0.2, Math.min(1.5, c.el + dy * 0.008));
      }
      requestDraw();
    });
    const end = () => { drag = null; };
    canvas.addEventListener("pointerup", end);
    canvas.addEventListener("pointercancel", end);
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      st.cam.dist = Math.max(0.3, Math.min(500, st.cam.dist * Math.exp(e.deltaY * 0.0012)));
      requestDraw();
    }, { passive: false });
    canvas.addEventListener("dblclick", () => { resetCamera(); requestDraw(); });
    window.addEventListener("keydown", (e) => {
      if (e.target && e.target.tagName === "SELECT") return;
      const step = e.shiftKey ? 10 : 1;
      if (e.code === "Space") { e.preventDefault(); setPlaying(!st.playing); }
      else if (e.key === "ArrowRight") { e.preventDefault(); setPlaying(false); setFrame(st.frame + step, false); }
      else if (e.key === "ArrowLeft") { e.preventDefault(); setPlaying(false); setFrame(st.frame - step, false); }
      else if (e.key === "Home") setFrame(0, false);
      else if (e.key === "End") setFrame(scenes[st.scene].F - 1, false);
    });
    window.addEventListener("resize", resize);
  }

  // ---- start -------------------------------------------------------------------------------

  async function start() {
    meta = JSON.parse($("socdiff-meta").textContent);
    const buf = await inflate($("socdiff-data").textContent);
    if (buf.length !== meta.raw_bytes) throw new Error("embedded data is damaged (" + buf.length + " of " + meta.raw_bytes + " bytes)");
    scenes = meta.scenes.map((m) => decodeScene(m, buf));
    st.signals = meta.show_signals !== false;
    $("signals").checked = st.signals;
    const sel = $("scene");
    scenes.forEach((s, i) => sel.add(new Option(s.name + " (" + s.samples.length + " × " + s.F + " frames)", String(i))));
    $("scene-wrap").hidden = scenes.length < 2;
    body.dataset.scenes = String(scenes.length);
    const opts = {};
    for (const part of location.hash.replace(/^#/, "").split("&")) {
      if (!part) continue;
      const [k, v] = part.split("=");
      opts[decodeURIComponent(k)] = v === undefined ? "" : decodeURIComponent(v);
    }
    const si = Number(opts.scene);
    if (Number.isInteger(si) && si >= 0 && si < scenes.length) sel.value = String(si);
    if (opts.sample !== undefined) st.sample = opts.sample;
    if (opts.speed) st.speed = Number(opts.speed) || 1;
    $("speed").value = String(st.speed);
    bindInput();
    $("message").hidden = true;
    selectScene(Number(sel.value) || 0);
    if (opts.frame) setFrame(Number(opts.frame), false);
    resize();
    pixelCounts();
    body.dataset.loadMs = String(Math.round(performance.now()));
    body.dataset.ready = "1";
    if ("autoplay" in opts) $("play").click();
  }

  start().catch((e) => fail("cannot show the motion: " + (e && e.message ? e.message : e)));
})();
