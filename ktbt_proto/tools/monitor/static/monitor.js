// ktbt monitor: the page. Plain JavaScript, no build step.
// Every piece of fleet data (peer names, item text, reasons) reaches the DOM as text only
// (textContent, setAttribute), never as markup. Batches arrive by server-sent events every
// 100 ms at most; they are applied to the model at once and drawn at the next animation frame.
"use strict";

(function () {
  const KEEP = 100; // transfers and refusals listed
  const SLOW = { lists: 250, timeline: 1000, detail: 250 }; // ms between two redraws of these
  const last = { lists: 0, timeline: 0, detail: 0 };
  const RECENT = 50; // events kept per peer
  const model = {
    peers: new Map(), // name -> {status, since, signed, knows: Map(item -> how), recent: []}
    items: new Map(), // digest -> sequence
    transfers: [],
    refusals: [],
    timeline: new Map(), // item -> [[ms, count]]
    stats: { drops: {}, events: 0 },
    transfersSeen: 0,
    refusalsSeen: 0,
  };
  const dirty = { peers: true, matrix: true, transfers: true, refusals: true, timeline: true, detail: true, stats: true };
  let selected = null;
  let scheduled = false;
  const cells = new Map(); // peer + "\u0000" + item -> td
  const pendingCells = new Set();
  const probe = {
    // what the tests and the benchmark read (window.ktbtMonitor)
    batches: 0,
    changes: 0,
    lastBatchAt: 0,
    batchGaps: [], // ms between two applied batches (the last 200)
    frameTimes: [], // ms spent drawing a frame (the last 200)
    lags: [], // ms from an event's time at its peer to its drawing here (the last 200)
    maxLag: 0,
    errors: 0,
    timelineItems: () => [...model.timeline.keys()], // bounded by the items kept
    itemCount: () => model.items.size,
    spreading: { top: 0, reach: {} }, // what the chart last drew: its y axis's top, each line's last count
  };
  window.ktbtMonitor = probe;

  function el(tag, text, cls) {
    const node = document.createElement(tag);
    if (text !== undefined && text !== null) node.textContent = String(text);
    if (cls) node.className = cls;
    return node;
  }
  function keep(list, value, most) {
    list.push(value);
    if (list.length > most) list.splice(0, list.length - most);
  }
  function shortKey(key) {
    return key ? key.slice(0, 8) + "\u2026" : "";
  }
  function clock(t) {
    const ms = Date.parse(t);
    return Number.isNaN(ms) ? String(t) : new Date(ms).toISOString().slice(11, 23);
  }
  function shown(sequence) {
    // <c>(TargetSeen,colour=2)<c>(!X) -> TargetSeen(colour=2), !X  (text only, never parsed as markup)
    const parts = String(sequence).split("<c>(").filter((p) => p.length);
    if (!parts.length) return String(sequence);
    return parts
      .map((p) => {
        const body = p.endsWith(")") ? p.slice(0, -1) : p;
        const comma = body.indexOf(",");
        return comma < 0 ? body : body.slice(0, comma) + "(" + body.slice(comma + 1) + ")";
      })
      .join(", ");
  }

  const MAX_ROWS = 200;
  const MAX_COLS = 100;
  const drawn = { peers: new Set(), items: new Set() };

  function peer(name) {
    let p = model.peers.get(name);
    if (!p) {
      p = { status: "heard", since: 0, signed: false, knows: new Map(), recent: [], queries_lost: 0, dropped: 0, lost_events: 0 };
      model.peers.set(name, p);
      dirty.matrix = true;
    }
    return p;
  }

  function snapshot(state) {
    model.peers.clear();
    model.items.clear();
    model.timeline.clear();
    cells.clear();
    for (const [item, sequence] of Object.entries(state.items)) model.items.set(item, sequence);
    for (const view of state.peers) {
      const p = peer(view.peer);
      Object.assign(p, { status: view.status, since: view.since, signed: view.signed, queries_lost: view.queries_lost, dropped: view.dropped, lost_events: view.lost_events });
      for (const [item, how] of Object.entries(view.knows)) p.knows.set(item, { how: how, at: 0 });
      p.recent = view.recent.slice(-RECENT);
    }
    model.transfers = state.transfers.slice(-KEEP);
    model.refusals = state.refusals.slice(-KEEP);
    model.transfersSeen = state.transfers.length;
    model.refusalsSeen = state.refusals.length;
    for (const point of state.timeline) spread(point);
    for (const key of Object.keys(dirty)) dirty[key] = true;
  }

  function spread(point) {
    if (!model.items.has(point.item)) return; // an item no longer kept: its line went with it
    let line = model.timeline.get(point.item);
    if (!line) model.timeline.set(point.item, (line = []));
    const ms = Date.parse(point.t);
    if (!Number.isNaN(ms)) keep(line, [ms, point.count], 2000);
  }

  function apply(change, now) {
    switch (change.k) {
      case "peer": {
        const p = peer(change.peer);
        // a status is redrawn on its row (drawRows); only a new peer rebuilds the matrix
        Object.assign(p, { status: change.status, since: change.since, signed: change.signed, queries_lost: change.queries_lost, dropped: change.dropped, lost_events: change.lost_events });
        dirty.peers = true;
        break;
      }
      case "item":
        model.items.set(change.item, change.sequence);
        if (drawn.items.has(change.item) || drawn.items.size < MAX_COLS) dirty.matrix = true;
        break;
      case "unpeer":
        model.peers.delete(change.peer);
        dirty.matrix = dirty.peers = true;
        break;
      case "unitem":
        model.items.delete(change.item);
        if (model.timeline.delete(change.item)) dirty.timeline = true;
        dirty.matrix = true;
        break;
      case "know": {
        const p = peer(change.peer);
        if (change.how) p.knows.set(change.item, { how: change.how, at: now, t: change.t });
        else p.knows.delete(change.item);
        pendingCells.add(change.peer + "\u0000" + change.item);
        break;
      }
      case "event": {
        const p = peer(change.peer);
        keep(p.recent, change, RECENT);
        if (change.peer === selected) dirty.detail = true;
        const ms = Date.parse(change.t);
        if (!Number.isNaN(ms) && pendingLag.length < 5000) pendingLag.push(ms); // a hidden tab draws nothing
        break;
      }
      case "transfer":
        keep(model.transfers, change, KEEP);
        model.transfersSeen += 1;
        dirty.transfers = true;
        break;
      case "refusal":
        keep(model.refusals, change, KEEP);
        model.refusalsSeen += 1;
        dirty.refusals = true;
        break;
      case "spread":
        spread(change);
        dirty.timeline = true;
        break;
      default:
        break;
    }
  }
  let pendingLag = [];

  function onBatch(text) {
    let batch;
    try {
      batch = JSON.parse(text);
    } catch (e) {
      probe.errors += 1;
      return;
    }
    const now = Date.now();
    if (probe.lastBatchAt) keep(probe.batchGaps, now - probe.lastBatchAt, 200);
    probe.lastBatchAt = now;
    probe.batches += 1;
    if (batch.snapshot) snapshot(batch.snapshot);
    for (const change of batch.changes || []) apply(change, now);
    probe.changes += (batch.changes || []).length;
    model.stats = batch.stats || model.stats;
    dirty.stats = true;
    schedule();
  }

  function schedule() {
    if (!scheduled) {
      scheduled = true;
      requestAnimationFrame(draw);
    }
  }

  // -- drawing ---------------------------------------------------------------------------------

  function draw() {
    scheduled = false;
    const start = performance.now();
    const now = Date.now();
    if (dirty.matrix) drawMatrix();
    else drawCells(now);
    if (dirty.peers) drawRows();
    // The lists, the timeline and the detail are redrawn a few times a second at most, so a
    // busy fleet costs a frame the cells that changed and little more.
    let later = false;
    if (dirty.transfers || dirty.refusals) {
      if (now - last.lists >= SLOW.lists) {
        last.lists = now;
        if (dirty.transfers) drawTransfers();
        if (dirty.refusals) drawRefusals();
      } else later = true;
    }
    if (dirty.timeline) {
      if (now - last.timeline >= SLOW.timeline) {
        last.timeline = now;
        drawTimeline();
      } else later = true;
    }
    if (dirty.detail) {
      if (now - last.detail >= SLOW.detail) {
        last.detail = now;
        drawDetail();
      } else later = true;
    }
    if (dirty.stats) drawStats();
    if (later) setTimeout(schedule, 100);
    for (const ms of pendingLag) {
      const lag = now - ms;
      keep(probe.lags, lag, 200);
      if (lag > probe.maxLag) probe.maxLag = lag;
    }
    pendingLag = [];
    keep(probe.frameTimes, performance.now() - start, 200);
  }

  function itemOrder() {
    return [...model.items.entries()].sort((a, b) => (a[1] < b[1] ? -1 : a[1] > b[1] ? 1 : 0));
  }

  function drawMatrix() {
    dirty.matrix = false;
    dirty.peers = true;
    const table = document.getElementById("matrix");
    const head = el("tr");
    head.appendChild(el("th", "peer"));
    const all = itemOrder();
    const items = all.slice(0, MAX_COLS); // a bounded matrix: what is not drawn is said
    for (const [item, sequence] of items) {
      const th = el("th", shown(sequence), "item");
      th.title = sequence;
      th.setAttribute("data-item", item);
      head.appendChild(th);
    }
    table.tHead.replaceChildren(head);
    const rows = [];
    cells.clear();
    const everyone = [...model.peers.keys()].sort();
    const names = everyone.slice(0, MAX_ROWS);
    drawn.peers = new Set(names);
    drawn.items = new Set(items.map(([item]) => item));
    const hidden = [];
    if (everyone.length > names.length) hidden.push(everyone.length - names.length + " peers");
    if (all.length > items.length) hidden.push(all.length - items.length + " items");
    document.getElementById("matrix-more").textContent = hidden.length ? hidden.join(" and ") + " not drawn" : "";
    const now = Date.now();
    for (const name of names) {
      const tr = el("tr");
      tr.setAttribute("data-peer", name);
      const th = el("th", name, "peer-name");
      th.addEventListener("click", () => select(name));
      tr.appendChild(th);
      for (const [item] of items) {
        const td = el("td", null, "cell");
        td.setAttribute("data-item", item);
        cells.set(name + "\u0000" + item, td);
        fillCell(td, name, item, now);
        tr.appendChild(td);
      }
      rows.push(tr);
    }
    table.tBodies[0].replaceChildren(...rows);
    pendingCells.clear();
  }

  function fillCell(td, name, item, now) {
    const k = model.peers.get(name).knows.get(item);
    const how = k ? k.how : "";
    if (td.getAttribute("data-how") === how) return;
    td.setAttribute("data-how", how);
    td.className = "cell " + how;
    td.textContent = how === "learned" ? "\u25CF" : how === "known" ? "\u25CB" : "";
    td.title = how === "learned" && k.t ? "learned " + clock(k.t) : how;
    if (k && !k.shownAt) k.shownAt = now; // the first time drawn, kept across rebuilds
    td.setAttribute("data-shown-at", String(k ? k.shownAt : now));
  }

  function drawCells(now) {
    for (const key of pendingCells) {
      const td = cells.get(key);
      if (!td) {
        const cut = key.indexOf("\u0000");
        // a peer or item not drawn yet: rebuild while the matrix has room for it
        const newPeer = !drawn.peers.has(key.slice(0, cut)) && drawn.peers.size < MAX_ROWS;
        const newItem = !drawn.items.has(key.slice(cut + 1)) && drawn.items.size < MAX_COLS;
        if (newPeer || newItem) dirty.matrix = true;
        continue;
      }
      const cut = key.indexOf("\u0000");
      fillCell(td, key.slice(0, cut), key.slice(cut + 1), now);
    }
    pendingCells.clear();
    if (dirty.matrix) drawMatrix();
  }

  function drawRows() {
    dirty.peers = false;
    for (const tr of document.getElementById("matrix").tBodies[0].rows) {
      const name = tr.getAttribute("data-peer");
      const p = model.peers.get(name);
      if (!p) continue;
      tr.className = "status-" + p.status + (name === selected ? " selected" : "");
      tr.setAttribute("data-status", p.status);
      const th = tr.cells[0];
      th.title = p.status + (p.signed ? ", signed events" : ", unsigned events") + (p.queries_lost ? ", " + p.queries_lost + " queries lost" : "");
    }
  }

  function drawTransfers() {
    dirty.transfers = false;
    const out = [];
    for (const t of model.transfers.slice().reverse()) {
      const li = el("li", null, "transfer");
      li.appendChild(el("time", clock(t.t)));
      li.appendChild(el("span", t.teacher || "?", "who"));
      li.appendChild(el("span", "\u2192", "arrow"));
      li.appendChild(el("span", t.learner, "who"));
      li.appendChild(el("span", shown(model.items.get(t.item) || t.item), "what"));
      li.appendChild(el("span", t.author ? "author " + shortKey(t.author) : "unsigned item", t.author ? "signed" : "unsigned"));
      li.appendChild(el("span", t.signed ? "event signed" : "event unsigned", t.signed ? "signed" : "unsigned"));
      out.push(li);
    }
    document.getElementById("transfers").replaceChildren(...out);
  }

  function drawRefusals() {
    dirty.refusals = false;
    const out = [];
    for (const r of model.refusals.slice().reverse()) {
      const li = el("li", null, "refusal");
      li.appendChild(el("time", clock(r.t)));
      li.appendChild(el("span", r.peer, "who"));
      li.appendChild(el("span", r.where, "where"));
      li.appendChild(el("span", r.reason, "reason"));
      out.push(li);
    }
    document.getElementById("refusals").replaceChildren(...out);
  }

  const COLOURS = ["#1b9e77", "#d95f02", "#7570b3", "#e7298a", "#66a61e", "#e6ab02", "#a6761d", "#666666"];
  const DASHES = [[], [8, 4], [2, 3], [10, 3, 2, 3]];
  // Lines that coincide (items spreading together) stay told apart: each has its colour and
  // dash, and the earlier ones are drawn wider, so a later line lies inside an earlier one.
  function lineStyle(ctx, i, n) {
    ctx.strokeStyle = COLOURS[i % COLOURS.length];
    ctx.setLineDash(DASHES[i % DASHES.length]);
    ctx.lineWidth = 1.5 + Math.max(0, Math.min(n, 4) - 1 - i);
  }
  function swatch(i, n) {
    const c = el("canvas");
    c.width = 28;
    c.height = 10;
    const ctx = c.getContext("2d");
    lineStyle(ctx, i, n);
    ctx.beginPath();
    ctx.moveTo(0, 5);
    ctx.lineTo(28, 5);
    ctx.stroke();
    return c;
  }

  // The plot fills its canvas, sized to the box the page gives it (so the page never overflows);
  // the axis titles and the legend are elements beside and under it, never over the lines.
  function drawTimeline() {
    dirty.timeline = false;
    const canvas = document.getElementById("timeline");
    const ratio = window.devicePixelRatio || 1;
    const cssW = Math.max(120, canvas.clientWidth);
    const cssH = Math.max(80, canvas.clientHeight);
    if (canvas.width !== Math.round(cssW * ratio)) canvas.width = Math.round(cssW * ratio);
    if (canvas.height !== Math.round(cssH * ratio)) canvas.height = Math.round(cssH * ratio);
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, cssW, cssH);
    let t0 = Infinity;
    let t1 = -Infinity;
    for (const line of model.timeline.values())
      for (const [ms] of line) {
        t0 = Math.min(t0, ms);
        t1 = Math.max(t1, ms);
      }
    const legend = [];
    const total = Math.max(1, model.peers.size);
    const reach = {};
    const left = 34;
    const top = 8;
    const w = cssW - left - 10;
    const h = cssH - top - 20;
    ctx.font = "11px sans-serif";
    ctx.fillStyle = "#444";
    ctx.strokeStyle = "#e3e3e3";
    ctx.lineWidth = 1;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    for (const share of [0, 0.25, 0.5, 0.75, 1]) {
      const y = top + h - share * h;
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + w, y);
      ctx.stroke();
      ctx.fillText(String(Math.round(share * total)), left - 4, y);
    }
    ctx.strokeStyle = "#999";
    ctx.strokeRect(left, top, w, h);
    ctx.textBaseline = "top";
    const span = t0 < Infinity ? Math.max(1000, t1 - t0) : 1000;
    for (const share of [0, 0.5, 1]) {
      ctx.textAlign = share === 0 ? "left" : share === 1 ? "right" : "center";
      ctx.fillText(((share * span) / 1000).toFixed(1), left + share * w, top + h + 4);
    }
    if (t0 < Infinity) {
      const n = model.timeline.size;
      let i = 0;
      for (const [item, line] of model.timeline) {
        ctx.save();
        ctx.beginPath();
        ctx.rect(left, top, w, h);
        ctx.clip();
        lineStyle(ctx, i, n);
        ctx.beginPath();
        let y = top + h;
        ctx.moveTo(left, y);
        for (const [ms, count] of line) {
          const x = left + ((ms - t0) / span) * w;
          ctx.lineTo(x, y);
          y = top + h - (count / total) * h;
          ctx.lineTo(x, y);
        }
        ctx.lineTo(left + w, y);
        ctx.stroke();
        ctx.restore();
        reach[item] = line.length ? line[line.length - 1][1] : 0;
        const li = el("li");
        li.setAttribute("data-item", item);
        li.appendChild(swatch(i, n));
        li.appendChild(el("span", shown(model.items.get(item) || item)));
        legend.push(li);
        i += 1;
      }
    }
    document.getElementById("timeline-legend").replaceChildren(...legend);
    probe.spreading = { top: total, reach: reach };
  }
  window.addEventListener("resize", () => {
    dirty.timeline = true;
    last.timeline = 0;
    schedule();
  });

  function select(name) {
    selected = name;
    last.detail = 0;
    dirty.detail = true;
    dirty.peers = true;
    schedule();
    fetchTree(name);
  }

  // The peer's control tree, asked of it when it is selected (spec/protocol.md section 10);
  // shown as text only, and only if it is still the peer selected.
  function fetchTree(name) {
    const pre = document.getElementById("detail-control");
    pre.textContent = "(asking " + name + " for its tree)";
    fetch("/api/tree/" + encodeURIComponent(name))
      .then(r => r.json())
      .then(body => {
        if (selected !== name) return;
        pre.textContent = typeof body.tree === "string" ? body.tree : "(no tree from " + name + ": it publishes no events, or gave none that could be read)";
      })
      .catch(() => { if (selected === name) pre.textContent = "(the tree could not be fetched)"; });
  }

  function drawDetail() {
    dirty.detail = false;
    if (selected === null) return;
    const p = model.peers.get(selected);
    document.getElementById("detail-name").textContent = selected;
    if (!p) return;
    document.getElementById("detail-status").textContent =
      p.status + " \u00B7 " + (p.signed ? "signed events" : "unsigned events") + " \u00B7 " + p.queries_lost + " queries lost \u00B7 " + p.dropped + " events dropped by the peer, " + p.lost_events + " lost on the way";
    const root = el("li", selected, "node");
    const kids = el("ul");
    for (const [how, label] of [["known", "known (served, or before the monitor started)"], ["learned", "learned while watched"]]) {
      const slot = el("li", label, "node slot");
      const list = el("ul");
      for (const [item, k] of p.knows) {
        if (k.how !== how) continue;
        const leaf = el("li", shown(model.items.get(item) || item), "node item");
        leaf.title = model.items.get(item) || item;
        list.appendChild(leaf);
      }
      slot.appendChild(list);
      kids.appendChild(slot);
    }
    root.appendChild(kids);
    document.getElementById("detail-tree").replaceChildren(root);
    const events = [];
    for (const e of p.recent.slice().reverse()) {
      const li = el("li", null, "event");
      li.appendChild(el("time", clock(e.t)));
      li.appendChild(el("span", e.event, "kind"));
      const rest = [];
      for (const key of ["sender", "to", "teacher", "where", "reason"]) if (e[key] !== undefined) rest.push(key + " " + e[key]);
      if (e.item) rest.push(shown(model.items.get(e.item) || e.item));
      li.appendChild(el("span", rest.join(" \u00B7 "), "rest"));
      events.push(li);
    }
    document.getElementById("detail-events").replaceChildren(...events);
  }

  function drawStats() {
    dirty.stats = false;
    let present = 0;
    let gone = 0;
    let lost = 0;
    let peerDropped = 0;
    for (const p of model.peers.values()) {
      if (p.status === "present" || p.status === "heard") present += 1;
      if (p.status === "gone") gone += 1;
      lost += p.queries_lost || 0;
      peerDropped += (p.dropped || 0) + (p.lost_events || 0);
    }
    const drops = model.stats.drops || {};
    const dropped = Object.values(drops).reduce((a, b) => a + b, 0);
    const set = (id, text) => {
      document.getElementById(id).textContent = String(text);
    };
    set("stat-present", present);
    set("stat-gone", gone);
    set("stat-events", model.stats.events || 0);
    set("stat-transfers", model.transfersSeen);
    set("stat-refusals", model.refusalsSeen);
    set("stat-lost", lost);
    set("stat-dropped", dropped);
    document.getElementById("stat-dropped").title = Object.entries(drops).map(([k, v]) => k + ": " + v).join(", ");
    const reasons = model.stats.reasons || {};
    const lines = [];
    for (const [why, count] of Object.entries(drops)) {
      const li = el("li", null, "dropped");
      li.setAttribute("data-why", why);
      li.appendChild(el("span", why + ": " + count, "why"));
      for (const reason of reasons[why] || []) li.appendChild(el("span", reason, "reason"));
      lines.push(li);
    }
    document.getElementById("dropped").replaceChildren(...lines);
    set("stat-peer-dropped", peerDropped);
    const lag = probe.lags.length ? probe.lags[probe.lags.length - 1] : null;
    set("stat-lag", lag === null ? "-" : lag + " ms");
  }

  // -- the stream ------------------------------------------------------------------------------

  function connect() {
    const badge = document.getElementById("connection");
    const source = new EventSource("/api/stream");
    source.onopen = () => {
      badge.textContent = "live";
      badge.className = "badge live";
    };
    source.onmessage = (message) => onBatch(message.data);
    source.onerror = () => {
      badge.textContent = "reconnecting";
      badge.className = "badge down";
    };
  }
  connect();
})();
