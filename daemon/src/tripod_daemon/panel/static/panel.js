// SPDX-License-Identifier: BSD-3-Clause
// The panel's page: polls /api/state once a second, draws it, sends the three actions.
// Plain JavaScript, no build step, no outside resources.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  let imageSeq = -1;
  let stopArmedUntil = 0;

  function fmtBytes(n) {
    if (n === null || n === undefined) return "–";
    const u = ["B", "KiB", "MiB", "GiB", "TiB"];
    let i = 0;
    while (n >= 1024 && i < u.length - 1) { n /= 1024; i++; }
    return (i === 0 ? n.toFixed(0) : n.toFixed(n < 10 ? 2 : 1)) + " " + u[i];
  }
  function fmtDuration(s) {
    if (s === null || s === undefined) return "–";
    s = Math.floor(s);
    const h = Math.floor(s / 3600), m = Math.floor((s % 3600) / 60), sec = s % 60;
    const mm = String(m).padStart(2, "0"), ss = String(sec).padStart(2, "0");
    return h > 0 ? h + ":" + mm + ":" + ss : m + ":" + ss;
  }
  function fmtMinutes(m) {
    if (m === null || m === undefined) return "–";
    if (m >= 600) return Math.round(m / 60) + " h";
    if (m >= 60) return (m / 60).toFixed(1) + " h";
    return Math.round(m) + " min";
  }
  function clock(ns) {
    const d = new Date(ns / 1e6);
    return d.toLocaleTimeString([], { hour12: false });
  }
  function setText(id, t) { const e = $(id); if (e.textContent !== t) e.textContent = t; }

  // near red .. far blue; no return black
  const palette = new Uint8ClampedArray(256 * 3);
  for (let v = 1; v < 256; v++) {
    const t = (v - 1) / 254, h = 240 * t;  // hue 0 (near) .. 240 (far)
    const c = 1, x = c * (1 - Math.abs(((h / 60) % 2) - 1));
    let r, g, b;
    if (h < 60) [r, g, b] = [c, x, 0]; else if (h < 120) [r, g, b] = [x, c, 0];
    else if (h < 180) [r, g, b] = [0, c, x]; else [r, g, b] = [0, x, c];
    palette[v * 3] = r * 255; palette[v * 3 + 1] = g * 255; palette[v * 3 + 2] = b * 255;
  }
  function drawImage(img) {
    if (!img.grey_b64) return;
    const bin = atob(img.grey_b64);
    const cv = $("range"), ctx = cv.getContext("2d");
    const data = ctx.createImageData(img.cols, img.rows);
    for (let i = 0; i < bin.length; i++) {
      const v = bin.charCodeAt(i), o = i * 4;
      data.data[o] = palette[v * 3]; data.data[o + 1] = palette[v * 3 + 1];
      data.data[o + 2] = palette[v * 3 + 2]; data.data[o + 3] = 255;
    }
    ctx.putImageData(data, 0, 0);
    imageSeq = img.seq;
  }

  function render(s) {
    const conn = $("conn");
    const fresh = s.connected && s.status_age_s !== null && s.status_age_s < 3;
    conn.textContent = fresh ? "live" : (s.connected ? "no status" : "offline");
    conn.className = "badge " + (fresh ? "ok" : "bad");
    const r = s.recording;
    setText("rec-state", r.recording ? "● RECORDING" : r.state.toUpperCase());
    $("rec").className = "tile rec-" + (r.recording ? "recording" : r.state);
    setText("rec-file", r.file || "no file");
    setText("rec-elapsed", fmtDuration(r.elapsed_s));
    setText("rec-size", fmtBytes(r.file_bytes));
    setText("disk-free", fmtBytes(r.free_bytes));
    setText("disk-left", fmtMinutes(r.minutes_left));
    const w = s.warnings || [];
    $("warnings").hidden = w.length === 0;
    const wl = $("warn-list");
    const wtext = w.join("\n");
    if (wl.dataset.t !== wtext) {
      wl.dataset.t = wtext;
      wl.replaceChildren(...w.map((t) => { const li = document.createElement("li"); li.textContent = t; return li; }));
    }
    const l = s.lidar;
    setText("lidar-rate", l.rate.toFixed(0));
    setText("lidar-drops", String(l.drops));
    setText("lidar-mode", l.return_mode || "–");
    setText("lidar-pps", l.pps === "unknown" ? "no data" : l.pps);
    const m = s.imu;
    setText("imu-state", m.present ? m.state : "not configured");
    setText("imu-rate", m.present ? m.rate.toFixed(0) : "–");
    setText("imu-tilt", m.tilt_deg === null ? "–" : m.tilt_deg.toFixed(1) + "°");
    setText("imu-rp", m.roll_deg === null ? "–" : m.roll_deg.toFixed(1) + "° / " + m.pitch_deg.toFixed(1) + "°");
    drawImage(s.image);
    const img = s.image;
    setText("range-cap", img.age_s === null ? "no picture yet" :
      img.packets + " packets, " + img.age_s.toFixed(1) + " s ago; no return in " + img.empty_pct + " %");
    const marks = s.marks || [];
    setText("marks-n", marks.length ? "(" + marks.length + ")" : "");
    $("marks-none").hidden = marks.length > 0;
    const ol = $("marks");
    if (ol.children.length !== marks.length) {
      ol.replaceChildren(...marks.map((k) => {
        const li = document.createElement("li");
        li.textContent = clock(k.host_time_ns) + (k.label ? "  " + k.label : "");
        return li;
      }));
    }
  }

  async function poll() {
    try {
      const resp = await fetch("/api/state?have=" + imageSeq, { cache: "no-store", credentials: "same-origin" });
      if (resp.status === 401) { location.reload(); return; }
      if (resp.ok) render(await resp.json());
    } catch (e) {
      const conn = $("conn"); conn.textContent = "panel offline"; conn.className = "badge bad";
    }
    setTimeout(poll, 1000);
  }

  function toast(text, ok) {
    const t = $("toast"); t.textContent = text; t.className = "toast " + (ok ? "ok" : "err");
  }
  async function act(command, body) {
    const btns = document.querySelectorAll(".actions .btn");
    btns.forEach((b) => (b.disabled = true));
    try {
      const resp = await fetch("/api/control/" + command, {
        method: "POST", credentials: "same-origin",
        headers: { "Content-Type": "application/json" }, body: JSON.stringify(body || {}),
      });
      if (resp.status === 401) { location.reload(); return null; }
      const r = await resp.json();
      if (!resp.ok || !r.ok) { toast("Refused: " + (r.error || resp.status), false); return null; }
      return r;
    } catch (e) {
      toast("No answer from the panel", false); return null;
    } finally {
      btns.forEach((b) => (b.disabled = false));
    }
  }
  const base = (f) => (f ? f.split("/").pop() : "");
  $("btn-start").addEventListener("click", async () => {
    const r = await act("start");
    if (r) toast("Recording: " + base(r.file), true);
  });
  $("btn-stop").addEventListener("click", async () => {
    const b = $("btn-stop");
    if (Date.now() > stopArmedUntil) {  // two taps: a glove must not stop a recording
      stopArmedUntil = Date.now() + 3000;
      b.classList.add("armed"); b.textContent = "Tap again";
      setTimeout(() => { b.classList.remove("armed"); b.textContent = "Stop"; }, 3000);
      return;
    }
    stopArmedUntil = 0; b.classList.remove("armed"); b.textContent = "Stop";
    const r = await act("stop");
    if (r) toast("Stopped", true);
  });
  $("btn-mark").addEventListener("click", async () => {
    const label = $("mark-label").value.trim();
    const r = await act("mark", { label: label });
    if (r) {
      toast("Station marked" + (label ? " “" + label + "”" : "") + " at " +
            new Date().toLocaleTimeString([], { hour12: false }), true);
      $("mark-label").value = "";
    }
  });
  poll();
})();
