// rt2 label: the page. Keyboard first; the mouse clicks a centre or drags a box. Every change is a POST
// that the server answers only once the label is on disk. Boxes are COCO pixels [x, y, w, h]: the
// image covers [0, width] x [0, height]. Each tab has its own name (undo takes back only its own changes)
// and sends the revision of the labels it shows: a change made on an older one is refused and the tab reloads.
"use strict";

const rt2label = (() => {
  const canvas = document.getElementById("canvas");
  const ctx = canvas.getContext("2d");
  const $ = (id) => document.getElementById(id);
  const S = {
    state: null, cur: null, frame: null, img: null, edit: null, proposal: 0,
    lastSize: null, busy: false, placed: false, view: { scale: 1, ox: 0, oy: 0 }, drag: null, trainPoll: null,
    tab: "tab-" + Math.random().toString(36).slice(2, 12) + Date.now().toString(36), revision: null,
    fromProposal: null, confirm: null,
  };

  function message(text, kind) {
    const m = $("message");
    m.textContent = text || "";
    m.className = kind || "";
  }

  async function api(path, body) {
    const opts = body === undefined ? {} : {
      method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
    };
    let r;
    try {
      r = await fetch(path, opts);
    } catch (e) {
      throw new Error("the server does not answer (is rt2 label still running?)");
    }
    const data = await r.json().catch(() => ({ error: `HTTP ${r.status}` }));
    if (!r.ok) {
      const err = new Error(data.error || `HTTP ${r.status}`);
      err.conflict = Boolean(data.conflict);
      throw err;
    }
    if (typeof data.revision === "number") S.revision = data.revision;
    return data;
  }

  // -- drawing -------------------------------------------------------------------------------
  function layout() {
    canvas.width = canvas.clientWidth;
    canvas.height = canvas.clientHeight;
    if (!S.frame) return;
    const W = S.frame.width, H = S.frame.height;
    const scale = Math.min(canvas.width / W, canvas.height / H);
    S.view = { scale, ox: (canvas.width - W * scale) / 2, oy: (canvas.height - H * scale) / 2 };
  }

  function toScreen(b) {
    const v = S.view;
    return [v.ox + b[0] * v.scale, v.oy + b[1] * v.scale, b[2] * v.scale, b[3] * v.scale];
  }

  function toImage(ev) {
    const r = canvas.getBoundingClientRect(), v = S.view;
    return [(ev.clientX - r.left - v.ox) / v.scale, (ev.clientY - r.top - v.oy) / v.scale];
  }

  function strokeBox(b, colour, dash, text, below) {
    const [x, y, w, h] = toScreen(b);
    ctx.save();
    ctx.strokeStyle = colour;
    ctx.lineWidth = 2;
    ctx.setLineDash(dash);
    ctx.strokeRect(x, y, w, h);
    if (text) {
      ctx.fillStyle = colour;
      ctx.font = "13px sans-serif";
      ctx.fillText(text, x, below ? y + h + 14 : y - 4);
    }
    ctx.restore();
  }

  function draw() {
    layout();
    ctx.fillStyle = "#111";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    if (!S.frame || !S.img) return;
    const v = S.view;
    ctx.drawImage(S.img, v.ox, v.oy, S.frame.width * v.scale, S.frame.height * v.scale);
    S.frame.proposals.forEach((p, k) => strokeBox(p.box, p.auto ? "#d2a8ff" : "#f2cc60", [5, 4],
      p.auto ? `${k + 1}: cameras ${p.score.toFixed(2)} (${p.support} agree)` : `${k + 1}: ${p.score.toFixed(2)}`));
    const labels = S.frame.labels;
    if (labels) labels.forEach((b) => strokeBox(b, "#7ee787", [], "label", true));
    if (labels && labels.length === 0) {
      ctx.fillStyle = "rgba(255,123,114,0.9)";
      ctx.font = "bold 28px sans-serif";
      ctx.fillText("NO BALL", v.ox + 12, v.oy + 36);
    }
    if (S.edit) { strokeBox(S.edit, "#56d4ff", [], ""); drawZoom(); }
    if (S.drag && S.drag.now) {
      const [a, b] = [S.drag.start, S.drag.now];
      strokeBox([Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.abs(a[0] - b[0]), Math.abs(a[1] - b[1])], "#ffffff", [2, 2], "");
    }
  }

  // A magnified view of the box's surroundings (bottom left), so a small ball can be boxed exactly.
  function drawZoom() {
    const e = S.edit, side = Math.max(48, 3 * Math.max(e[2], e[3]));
    const sx = e[0] + e[2] / 2 - side / 2, sy = e[1] + e[3] / 2 - side / 2, out = 220;
    const x0 = 8, y0 = canvas.height - out - 8, k = out / side;
    ctx.save();
    ctx.fillStyle = "#000";
    ctx.fillRect(x0 - 2, y0 - 2, out + 4, out + 4);
    ctx.imageSmoothingEnabled = false;
    ctx.drawImage(S.img, sx, sy, side, side, x0, y0, out, out);
    ctx.strokeStyle = "#56d4ff";
    ctx.lineWidth = 1;
    ctx.strokeRect(x0 + (e[0] - sx) * k, y0 + (e[1] - sy) * k, e[2] * k, e[3] * k);
    ctx.restore();
  }

  // -- panels --------------------------------------------------------------------------------
  function renderPanels() {
    const st = S.state;
    if (!st) return;
    const c = st.counts;
    $("counts").textContent = `${c.labelled} of ${st.n_frames} frames labelled: ${c.with_ball} with a ball, ${c.no_ball} without` +
      (c.kept_from_file ? `; ${c.kept_from_file} more kept from the file` : "");
    const ol = $("suggestions");
    ol.innerHTML = "";
    st.suggestions.forEach((i) => {
      const li = document.createElement("li");
      li.textContent = `${st.frames[i].key}`;
      li.dataset.frame = i;
      if (i === S.cur) li.className = "current";
      li.onclick = () => show(i);
      ol.appendChild(li);
    });
    if (!st.suggestions.length) ol.innerHTML = "<li>every frame is labelled</li>";
    const f = S.frame;
    if (f) {
      const lab = f.labels === null ? "not labelled" : (f.labels.length ? `labelled: ${f.labels.length} ball(s)` : "labelled: no ball");
      $("frame-info").textContent = `frame ${f.i + 1}/${st.n_frames} · ${f.key} · ${lab}`;
    }
    $("paths").textContent = `source: ${st.source} · labels: ${st.annotations} · proposals by ${st.model}`;
    const sk = st.skipped || [];
    $("skipped").textContent = sk.length ? `${sk.length} unreadable image(s) skipped: ` + sk.map((x) => `${x.file} (${x.why})`).join("; ") : "";
    if (!$("colour").value && st.ball_colour) $("colour").value = st.ball_colour;
    renderTraining(st.training, st.can_train);
  }

  function renderTraining(t, canTrain) {
    S.state.training = t;
    if (canTrain !== undefined) S.state.can_train = canTrain;
    $("train-btn").disabled = !S.state.can_train || t.state === "running";
    const need = `label ${S.state.min_train_labels} frames (2 with a ball) to train`;
    const colour = t.ball_colour ? ` (${t.ball_colour} balls)` : "";
    let text = { idle: S.state.can_train ? "ready to train" : need, running: `training${colour}…`,
      done: `done${colour}: wrote ${t.model}`, failed: `failed${colour}, no model written (exit code ${t.returncode}): ${t.error}` }[t.state];
    $("train-state").textContent = text;
    $("train-state").className = t.state;
    $("train-figures").textContent = (t.figures || []).length ? "held-out figures: " + t.figures.join(" | ") : "";
    $("train-notes").textContent = (t.notes || []).length ? "note: " + t.notes.join(" | ") : "";
    $("train-log").textContent = t.log_tail || "";
    if (t.state === "running" && !S.trainPoll) {
      S.trainPoll = setInterval(async () => {
        try {
          const s = await api("/api/train");
          renderTraining(s);
          if (s.state !== "running") { clearInterval(S.trainPoll); S.trainPoll = null; }
        } catch (e) { message(e.message, "error"); }
      }, 1000);
    }
  }

  // -- navigation ----------------------------------------------------------------------------
  async function refreshState() {
    S.state = await api("/api/state");
  }

  // the cyan box: the label, else the best proposal, else none (no box at a made-up place)
  function defaultEdit(f) {
    if (f.labels && f.labels.length) return f.labels[0].slice();
    if (f.proposals.length) return f.proposals[0].box.slice();
    return null;
  }

  // keep: the message stays (it is about the change that led here); a move by the user clears it
  async function show(i, keep) {
    const f = await api(`/api/frame/${i}`);
    const img = new Image();
    await new Promise((ok, fail) => { img.onload = ok; img.onerror = () => fail(new Error(`frame ${i}: the image did not load`)); img.src = `/api/image/${i}`; });
    S.cur = i; S.frame = f; S.img = img; S.proposal = 0; S.edit = defaultEdit(f); S.confirm = null;
    S.fromProposal = !(f.labels && f.labels.length) && f.proposals.length ? 0 : null;
    S.placed = Boolean(f.proposals.length || (f.labels && f.labels.length));  // a box someone (model or user) put there
    if (!keep) message("");
    renderPanels();
    draw();
    canvas.dataset.frame = String(i);
  }

  // Space walks down the list (the current frame's successor in it, else its top), so it never bounces between two
  function nextSuggested() {
    const s = S.state.suggestions;
    if (!s.length) return null;
    const k = s.indexOf(S.cur);
    return s[(k + 1) % s.length];
  }

  // -- changes -------------------------------------------------------------------------------
  function clip(b) {
    const W = S.frame.width, H = S.frame.height;
    const x0 = Math.max(0, b[0]), y0 = Math.max(0, b[1]);
    const x1 = Math.min(W, b[0] + b[2]), y1 = Math.min(H, b[1] + b[3]);
    return [x0, y0, Math.max(0, x1 - x0), Math.max(0, y1 - y0)];
  }

  async function save(boxes) {
    if (S.busy || !S.frame) return;
    S.busy = true;
    try {
      const i = S.cur;
      const r = await api("/api/label", { frame: i, boxes, tab: S.tab, revision: S.revision });
      if (boxes.length) S.lastSize = [boxes[0][2], boxes[0][3]];
      message(boxes.length ? `saved frame ${i + 1}: ball at (${(boxes[0][0] + boxes[0][2] / 2).toFixed(1)}, ${(boxes[0][1] + boxes[0][3] / 2).toFixed(1)})` : `saved frame ${i + 1}: no ball`, "ok");
      await refreshState();
      const next = r.suggestions.find((j) => j !== i);
      await show(next === undefined ? i : next, true);
    } catch (e) {
      await failed(e);
    } finally {
      S.busy = false;
    }
  }

  async function undo() {
    if (S.busy) return;
    S.busy = true;
    try {
      const r = await api("/api/undo", { tab: S.tab, revision: S.revision });
      await refreshState();
      if (r.frame === null) message("nothing of this tab's to undo", "");
      else { message(`undid the change to frame ${r.frame + 1}`, "ok"); await show(r.frame, true); }
    } catch (e) { await failed(e); } finally { S.busy = false; }
  }

  // a refused change: say why; a revision conflict (another tab changed the labels) reloads what is on disk
  async function failed(e) {
    if (!e.conflict) { message(e.message, "error"); return; }
    try {
      await refreshState();
      await show(S.cur, true);
    } catch (x) { /* the message below still says what happened */ }
    message(e.message, "error");
  }

  async function train() {
    const colour = $("colour").value;
    if (!colour) { message("choose the ball colour to train on (orange, white or any) next to the Train button", "error"); $("colour").focus(); return; }
    try {
      const t = await api("/api/train", { ball_colour: colour });
      message(`training started on ${colour} balls`, "ok");
      renderTraining(t);
    } catch (e) { message(e.message, "error"); }
  }

  function acceptEdit() {
    if (!S.placed || !S.edit) {
      message("no proposal in this frame: click the ball, or press n for no ball", "error");
      return;
    }
    const b = clip(S.edit);
    if (b[2] < 1 || b[3] < 1) { message("the box is outside the image; move it in (i j k l) or press n for no ball", "error"); return; }
    const p = S.fromProposal === null ? null : S.frame.proposals[S.fromProposal];
    if (p && p.score < S.state.confirm_below && S.confirm !== S.cur) {  // an unsure proposal as it is: a second key
      S.confirm = S.cur;
      message(`proposal ${S.fromProposal + 1} is scored ${p.score.toFixed(2)}, below ${S.state.confirm_below}: look again; ` +
        "press Enter again to accept it, correct the box, or press n for no ball", "warn");
      return;
    }
    save([b]);
  }

  // -- input ---------------------------------------------------------------------------------
  function onKey(ev) {
    if (!S.frame || ev.ctrlKey && ev.key !== "z" || ev.metaKey || ev.altKey) return;
    if (ev.target && ev.target.tagName === "SELECT") return;
    const step = ev.shiftKey ? 10 : 1;
    const e = S.edit;
    let handled = true;
    switch (ev.key) {
      case "Enter": case "a": acceptEdit(); break;
      case "n": case "N": save([]); break;
      case "u": case "Backspace": undo(); break;
      case "z": if (ev.ctrlKey) undo(); else handled = false; break;
      case " ": case "s": { const n = nextSuggested(); if (n !== null) show(n).catch((x) => message(x.message, "error")); break; }
      case "ArrowRight": case ".": if (S.cur + 1 < S.state.n_frames) show(S.cur + 1); break;
      case "ArrowLeft": case ",": if (S.cur > 0) show(S.cur - 1); break;
      case "Home": show(0); break;
      case "End": show(S.state.n_frames - 1); break;
      case "Tab": if (S.frame.proposals.length) {
        S.proposal = (S.proposal + 1) % S.frame.proposals.length; S.edit = S.frame.proposals[S.proposal].box.slice();
        S.fromProposal = S.proposal; S.confirm = null; S.placed = true;
      } break;
      case "t": train(); break;
      default:
        if (e && "ijklIJKL+=-_".includes(ev.key)) {  // moving or resizing needs a box (none without a proposal: click the ball)
          if ("iI".includes(ev.key)) e[1] -= step;
          else if ("kK".includes(ev.key)) e[1] += step;
          else if ("jJ".includes(ev.key)) e[0] -= step;
          else if ("lL".includes(ev.key)) e[0] += step;
          // + and - grow / shrink by 1 px on each side (Shift is how many keyboards type "+": it does not change the step)
          else if ("+=".includes(ev.key)) { e[0] -= 1; e[1] -= 1; e[2] += 2; e[3] += 2; }
          else if (e[2] > 3 && e[3] > 3) { e[0] += 1; e[1] += 1; e[2] -= 2; e[3] -= 2; }
          S.placed = true; S.fromProposal = null;
        } else handled = false;
    }
    if (handled) { ev.preventDefault(); draw(); }
  }

  function onDown(ev) {
    if (ev.button !== 0 || !S.frame) return;
    canvas.focus();
    S.drag = { start: toImage(ev), screen: [ev.clientX, ev.clientY], now: null };
  }

  function onMove(ev) {
    if (!S.drag) return;
    if (Math.hypot(ev.clientX - S.drag.screen[0], ev.clientY - S.drag.screen[1]) >= 4) { S.drag.now = toImage(ev); draw(); }
  }

  function onUp(ev) {
    if (!S.drag) return;
    const d = S.drag;
    S.drag = null;
    const p = toImage(ev);
    let box;
    if (Math.hypot(ev.clientX - d.screen[0], ev.clientY - d.screen[1]) < 4) {  // a click: the ball's centre
      // the size of the last label (else of the cyan box), shrunk about the centre at the image's border
      const size = S.lastSize || (S.edit ? [S.edit[2], S.edit[3]] : [24, 24]);
      const hw = Math.min(size[0] / 2, p[0], S.frame.width - p[0]), hh = Math.min(size[1] / 2, p[1], S.frame.height - p[1]);
      box = [p[0] - hw, p[1] - hh, 2 * hw, 2 * hh];
    } else {
      box = [Math.min(d.start[0], p[0]), Math.min(d.start[1], p[1]), Math.abs(p[0] - d.start[0]), Math.abs(p[1] - d.start[1])];
    }
    S.edit = box;
    S.placed = true;
    S.fromProposal = null;
    draw();
    acceptEdit();
  }

  async function start() {
    try {
      await refreshState();
      const first = S.state.suggestions.length ? S.state.suggestions[0] : 0;
      await show(first);
      canvas.focus();
    } catch (e) { message(e.message, "error"); }
  }

  document.addEventListener("keydown", onKey);
  canvas.addEventListener("mousedown", onDown);
  window.addEventListener("mousemove", onMove);
  window.addEventListener("mouseup", onUp);
  window.addEventListener("resize", draw);
  $("train-btn").addEventListener("click", train);
  $("colour").addEventListener("change", () => { canvas.focus(); });
  start();
  return S;
})();
