// Flatlandia map viewer: one scene's reference map, its query cameras and, for a clicked query,
// its local map at the true pose and at each run's estimate. Plain SVG, no library, no network:
// the scene's data is the JSON block of the page. State is on window.flatlandiaViewer.
(function () {
  "use strict";
  const data = JSON.parse(document.getElementById("scene-data").textContent);
  const SVG_NS = "http://www.w3.org/2000/svg"; // the SVG namespace name, not a fetched address
  const svg = document.getElementById("map");
  const layers = {
    objects: document.getElementById("layer-objects"),
    cameras: document.getElementById("layer-cameras"),
    query: document.getElementById("layer-query"),
    scale: document.getElementById("layer-scale"),
  };
  const runs = new Map(data.runs.map((r) => [r.name, r]));
  const queries = new Map(data.queries.map((q) => [q.token, q]));
  const state = {
    selected: null,
    shown: new Set(data.runs.filter((r) => r.featured).map((r) => r.name)),
    splits: { train: true, val: true, test: true },
    view: { cx: 0, cy: 0, k: 1 },
    drawn: [],
  };
  window.flatlandiaViewer = state;

  // ------------------------------------------------------------------ geometry
  function size() {
    const r = svg.getBoundingClientRect();
    return [Math.max(r.width, 1), Math.max(r.height, 1)];
  }
  function toScreen(x, y) {
    const [w, h] = size();
    return [(x - state.view.cx) * state.view.k + w / 2, h / 2 - (y - state.view.cy) * state.view.k];
  }
  function toWorld(sx, sy) {
    const [w, h] = size();
    return [(sx - w / 2) / state.view.k + state.view.cx, state.view.cy - (sy - h / 2) / state.view.k];
  }
  function place(local, x, y, thetaDeg) {
    const t = (thetaDeg * Math.PI) / 180, c = Math.cos(t), s = Math.sin(t);
    return local.map(([u, v]) => [x + c * u - s * v, y + s * u + c * v]);
  }
  function fit(points) {
    if (!points.length) return;
    const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
    const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const [w, h] = size();
    state.view = { cx: (x0 + x1) / 2, cy: (y0 + y1) / 2, k: 0.9 * Math.min(w / Math.max(x1 - x0, 10), h / Math.max(y1 - y0, 10)) };
    render();
  }
  function mapPoints() {
    return data.objects.map((o) => [o[0], o[1]]).concat(data.queries.map((q) => [q.x, q.y]));
  }
  function queryPoints(q) {
    let pts = [[q.x, q.y]].concat(place(q.local, q.x, q.y, q.theta));
    for (const [name, e] of Object.entries(q.est)) {
      if (state.shown.has(name) && e[0] !== null) pts = pts.concat([[e[0], e[1]]], place(q.local, e[0], e[1], e[2]));
    }
    return pts;
  }

  // ------------------------------------------------------------------ drawing
  function el(tag, attrs, parent, title) {
    const node = document.createElementNS(SVG_NS, tag);
    for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
    if (title) {
      const t = document.createElementNS(SVG_NS, "title");
      t.textContent = title;
      node.appendChild(t);
    }
    if (parent) parent.appendChild(node);
    return node;
  }
  function arrowPath(x, y, thetaDeg, len, half) {
    const [sx, sy] = toScreen(x, y);
    const t = (-thetaDeg * Math.PI) / 180; // screen y points down
    const c = Math.cos(t), s = Math.sin(t);
    const tip = [sx + c * len, sy + s * len];
    const l = [sx - c * len * 0.35 - s * half, sy - s * len * 0.35 + c * half];
    const r = [sx - c * len * 0.35 + s * half, sy - s * len * 0.35 - c * half];
    return `M${tip[0]},${tip[1]}L${l[0]},${l[1]}L${r[0]},${r[1]}Z`;
  }
  function line(parent, a, b, attrs) {
    const [ax, ay] = toScreen(a[0], a[1]), [bx, by] = toScreen(b[0], b[1]);
    return el("line", { x1: ax, y1: ay, x2: bx, y2: by, ...attrs }, parent);
  }
  function drawObjects() {
    layers.objects.replaceChildren();
    for (const [x, y, k, idx] of data.objects) {
      const [sx, sy] = toScreen(x, y);
      const cls = data.classes[k];
      el("circle", { cx: sx, cy: sy, r: 4.5, fill: cls.colour, stroke: "#333", "stroke-width": 0.5 }, layers.objects, `${cls.label} (object ${idx})`);
    }
  }
  function drawCameras() {
    layers.cameras.replaceChildren();
    const order = ["train", "val", "test"];
    const sorted = data.queries.slice().sort((a, b) => order.indexOf(a.split) - order.indexOf(b.split));
    for (const q of sorted) {
      if (!state.splits[q.split]) continue;
      const big = q.split === "test";
      const g = el("g", { class: "camera" + (q.token === state.selected ? " selected" : ""), "data-token": q.token, "data-split": q.split }, layers.cameras);
      const [sx, sy] = toScreen(q.x, q.y);
      el("circle", { cx: sx, cy: sy, r: big ? 9 : 6, fill: "transparent" }, g);
      el("path", { d: arrowPath(q.x, q.y, q.theta, big ? 13 : 9, big ? 6 : 4), fill: data.splitColours[q.split], stroke: "#fff", "stroke-width": 0.8 }, g, `query ${q.token} (${q.split}, ${q.ref.length} objects)`);
      g.addEventListener("click", (ev) => {
        if (!dragged) select(q.token);
        ev.stopPropagation();
      });
    }
  }
  function drawPose(parent, q, pose, colour, dash, marker) {
    const objs = place(q.local, pose[0], pose[1], pose[2]);
    for (const p of objs) line(parent, [pose[0], pose[1]], p, { stroke: colour, "stroke-width": 1, "stroke-opacity": 0.45, "stroke-dasharray": dash });
    for (const p of objs) {
      const [sx, sy] = toScreen(p[0], p[1]);
      if (marker === "square") el("rect", { x: sx - 4, y: sy - 4, width: 8, height: 8, fill: colour }, parent);
      else el("path", { d: `M${sx - 4},${sy - 4}L${sx + 4},${sy + 4}M${sx - 4},${sy + 4}L${sx + 4},${sy - 4}`, stroke: colour, "stroke-width": 2.2 }, parent);
    }
    el("path", { d: arrowPath(pose[0], pose[1], pose[2], 16, 7), fill: colour, stroke: "#fff", "stroke-width": 1 }, parent);
    return objs;
  }
  function drawQuery() {
    layers.query.replaceChildren();
    state.drawn = [];
    const q = queries.get(state.selected);
    if (!q) return;
    const truthLayer = el("g", { "data-layer": "truth" }, layers.query);
    const objXY = new Map(data.objects.map((o) => [o[3], [o[0], o[1]]]));
    for (const idx of q.ref) {
      const p = objXY.get(idx);
      if (p) {
        const [sx, sy] = toScreen(p[0], p[1]);
        el("circle", { cx: sx, cy: sy, r: 9, fill: "none", stroke: data.truthColour, "stroke-width": 2 }, truthLayer);
      }
    }
    const truth = drawPose(truthLayer, q, [q.x, q.y, q.theta], data.truthColour, "", "square");
    state.drawn.push("truth");
    for (const r of data.runs) {
      const e = q.est[r.name];
      if (!e || !state.shown.has(r.name) || e[0] === null) continue;
      const g = el("g", { "data-layer": "estimate", "data-run": r.name }, layers.query);
      const objs = place(q.local, e[0], e[1], e[2]);
      const matches = e[7];
      objs.forEach((p, i) => {
        const target = matches ? objXY.get(matches[i]) : truth[i];
        if (!target) return;
        const wrong = matches && matches[i] !== q.ref[i];
        line(g, p, target, { stroke: wrong ? data.wrongColour : r.colour, "stroke-width": 1.3, "stroke-dasharray": matches ? r.dash : "2 3" });
      });
      drawPose(g, q, e, r.colour, r.dash, "cross");
      state.drawn.push(r.name);
    }
  }
  function niceLength(target) {
    const p = Math.pow(10, Math.floor(Math.log10(target)));
    return [1, 2, 5, 10].map((m) => m * p).filter((v) => v <= target).pop();
  }
  function drawScale() {
    layers.scale.replaceChildren();
    const [, h] = size();
    const len = niceLength(120 / state.view.k);
    const px = len * state.view.k;
    el("line", { x1: 20, y1: h - 20, x2: 20 + px, y2: h - 20, stroke: "#333", "stroke-width": 3 }, layers.scale);
    const t = el("text", { x: 20, y: h - 28, class: "obj-label" }, layers.scale);
    t.textContent = `${len} ${data.unit}   (north up)`;
  }
  function render() {
    const dim = state.selected ? "0.35" : "1"; // a selected query's layers stand out over the map
    layers.objects.setAttribute("opacity", dim);
    layers.cameras.setAttribute("opacity", dim);
    drawObjects();
    drawCameras();
    drawQuery();
    drawScale();
  }

  // ------------------------------------------------------------------ panel
  function esc(text) {
    const d = document.createElement("div");
    d.textContent = String(text);
    return d.innerHTML.replace(/"/g, "&quot;");
  }
  function fmt(v, digits) {
    return v === null ? "\u2014" : v.toFixed(digits);
  }
  function renderInfo() {
    const box = document.getElementById("query-info");
    const q = queries.get(state.selected);
    document.getElementById("fit-query").disabled = !q;
    if (!q) {
      box.innerHTML = '<h2>Query</h2><p class="none">No query selected.</p>';
      return;
    }
    let html = `<h2>Query ${esc(q.token)}</h2><p>${esc(q.split)} split, ${q.ref.length} objects; true pose (${q.x.toFixed(1)}, ${q.y.toFixed(1)}) ${data.unit}, heading ${q.theta.toFixed(1)}\u00b0. `;
    if (data.photoUrl) {
      html += `<a class="photo" href="${esc(data.photoUrl + encodeURIComponent(q.token))}" target="_blank" rel="noopener noreferrer">the photo on Mapillary</a>. `;
    }
    html += `<span class="line" style="border-color:${data.truthColour}"></span>true pose and local map</p>`;
    const names = Object.keys(q.est);
    if (!names.length) {
      box.innerHTML = html + `<p class="none">No run localizes this query (runs are evaluated on the test split).</p>`;
      return;
    }
    html += '<table id="errors"><tr><th></th><th>run</th><th class="num">m</th><th class="num">deg</th></tr>';
    let group = null;
    for (const r of data.runs) {
      const e = q.est[r.name];
      if (!e) continue;
      if (r.group !== group) {
        group = r.group;
        html += `<tr class="group"><th colspan="4">${esc(group)}</th></tr>`;
      }
      const checked = state.shown.has(r.name) ? "checked" : "";
      html += `<tr class="${r.featured ? "featured" : ""}" data-run="${esc(r.name)}"><td><input type="checkbox" data-run="${esc(r.name)}" ${checked}></td>`;
      html += `<td><span class="line ${r.dash ? "dashed" : ""}" style="border-color:${r.colour}"></span>${esc(r.label)}</td>`;
      html += `<td class="num">${e[0] === null ? "no pose" : fmt(e[3], 2)}</td><td class="num">${e[0] === null ? "" : fmt(e[4], 1)}</td></tr>`;
    }
    box.innerHTML = html + "</table>";
    box.querySelectorAll("input[data-run]").forEach((cb) =>
      cb.addEventListener("change", () => {
        if (cb.checked) state.shown.add(cb.dataset.run);
        else state.shown.delete(cb.dataset.run);
        drawQuery();
      })
    );
  }
  function renderLegend() {
    document.getElementById("title").textContent = data.title;
    const splits = document.getElementById("splits");
    for (const split of ["train", "val", "test"]) {
      const n = data.queries.filter((q) => q.split === split).length;
      const row = document.createElement("label");
      row.className = "row";
      row.innerHTML = `<input type="checkbox" data-split="${split}" checked><span class="swatch" style="background:${data.splitColours[split]}"></span>${split} (${n})`;
      row.querySelector("input").addEventListener("change", (ev) => {
        state.splits[split] = ev.target.checked;
        drawCameras();
      });
      splits.appendChild(row);
    }
    const classes = document.getElementById("classes");
    for (const c of data.classes) {
      const row = document.createElement("div");
      row.className = "row";
      row.innerHTML = `<span class="swatch" style="background:${c.colour}"></span>${esc(c.label)} (${c.count})`;
      classes.appendChild(row);
    }
  }
  function select(token) {
    state.selected = token;
    document.body.dataset.selected = token || "";
    renderInfo();
    render();
  }

  // ------------------------------------------------------------------ interaction
  let drag = null, dragged = false;
  svg.addEventListener("pointerdown", (ev) => {
    drag = { x: ev.clientX, y: ev.clientY, cx: state.view.cx, cy: state.view.cy };
    dragged = false;
  });
  window.addEventListener("pointermove", (ev) => {
    if (!drag) return;
    const dx = ev.clientX - drag.x, dy = ev.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) {
      dragged = true;
      svg.classList.add("dragging");
    }
    if (dragged) {
      state.view.cx = drag.cx - dx / state.view.k;
      state.view.cy = drag.cy + dy / state.view.k;
      render();
    }
  });
  window.addEventListener("pointerup", () => {
    drag = null;
    svg.classList.remove("dragging");
  });
  function zoomAt(sx, sy, factor) {
    const [wx, wy] = toWorld(sx, sy);
    state.view.k *= factor;
    const [nx, ny] = toWorld(sx, sy);
    state.view.cx += wx - nx;
    state.view.cy += wy - ny;
    render();
  }
  svg.addEventListener(
    "wheel",
    (ev) => {
      ev.preventDefault();
      const r = svg.getBoundingClientRect();
      zoomAt(ev.clientX - r.left, ev.clientY - r.top, Math.exp(-ev.deltaY * 0.0015));
    },
    { passive: false }
  );
  svg.addEventListener("click", (ev) => {
    if (!dragged && !ev.target.closest("#layer-query")) select(null);
  });
  document.getElementById("zoom-in").addEventListener("click", () => zoomAt(...size().map((v) => v / 2), 1.5));
  document.getElementById("zoom-out").addEventListener("click", () => zoomAt(...size().map((v) => v / 2), 1 / 1.5));
  document.getElementById("fit-map").addEventListener("click", () => fit(mapPoints()));
  document.getElementById("fit-query").addEventListener("click", () => fit(queryPoints(queries.get(state.selected))));
  window.addEventListener("keydown", (ev) => {
    if (ev.key === "Escape") select(null);
  });
  window.addEventListener("resize", render);

  renderLegend();
  renderInfo();
  fit(mapPoints());
  state.ready = true;
})();
