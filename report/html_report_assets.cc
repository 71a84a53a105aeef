#include "report/html_report_assets.h"

namespace tofu::report {

// System fonts only: a web font would be a download at view time.
const char* const kReportCss = R"CSS(
:root {
  --pass: #1a7f37; --pass-bg: #dafbe1; --fail: #cf222e; --fail-bg: #ffebe9;
  --muted: #59636e; --border: #d1d9e0; --head: #f6f8fa; --link: #0969da; --ink: #1f2328;
}
* { box-sizing: border-box; }
body { margin: 0; color: var(--ink); background: #fff; line-height: 1.45;
  font: 15px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, "Noto Sans", "DejaVu Sans", sans-serif; }
a { color: var(--link); text-decoration: none; }
a:hover { text-decoration: underline; }
code, pre, td.num { font-family: ui-monospace, "SFMono-Regular", "DejaVu Sans Mono", Menlo, Consolas, monospace; }
code { font-size: 0.92em; }
header.top { background: #24292f; color: #fff; padding: 18px 32px 16px; border-bottom: 6px solid var(--muted); }
header.top.pass { border-bottom-color: var(--pass); }
header.top.fail { border-bottom-color: var(--fail); }
header.top h1 { margin: 0; font-size: 1.6em; font-weight: 600; display: flex; align-items: center; gap: 14px; flex-wrap: wrap; }
header.top .sub { color: #c9d1d9; font-size: 0.9em; margin-top: 4px; word-break: break-all; }
header.top .description { color: #f0f3f6; margin-top: 6px; }
header.top .facts { color: #c9d1d9; font-size: 0.9em; margin-top: 4px; }
header.top .facts b { color: #fff; font-weight: 600; }
header.top nav { font-size: 0.9em; margin-bottom: 6px; }
header.top nav a { color: #9cd1ff; }
nav.toc { position: sticky; top: 0; z-index: 10; background: #fff; padding: 8px 0;
  border-bottom: 1px solid var(--border); font-size: 0.88em; display: flex; flex-wrap: wrap; gap: 4px 16px; }
section { scroll-margin-top: 48px; }
main { max-width: 1280px; margin: 0 auto; padding: 4px 32px 40px; }
h2 { font-size: 1.25em; margin: 30px 0 10px; padding-bottom: 4px; border-bottom: 1px solid var(--border); display: flex; align-items: center; gap: 10px; }
h3 { font-size: 1.05em; margin: 20px 0 6px; }
p { margin: 6px 0 10px; }
.muted, .caption, figcaption, .where { color: var(--muted); font-size: 0.88em; }
.badge { display: inline-block; padding: 2px 12px; border-radius: 14px; font-weight: 700; font-size: 0.62em;
  letter-spacing: 0.04em; vertical-align: middle; color: #fff; }
h2 .badge { font-size: 0.72em; }
.badge.pass { background: var(--pass); }
.badge.fail { background: var(--fail); }
table { border-collapse: collapse; font-size: 0.9em; margin: 8px 0 14px; }
th, td { border: 1px solid var(--border); padding: 4px 9px; text-align: left; vertical-align: top; }
th { background: var(--head); font-weight: 600; }
td.num { text-align: right; white-space: nowrap; font-size: 0.95em; }
tr.pass td.result { background: var(--pass-bg); color: var(--pass); font-weight: 700; }
tr.fail td { background: var(--fail-bg); }
tr.fail td.result { color: var(--fail); font-weight: 700; }
td.cell.pass { background: var(--pass-bg); color: var(--pass); }
td.cell.fail { background: #ffcecb; color: var(--fail); font-weight: 700; }
td.cell.neutral { background: var(--head); color: var(--muted); }
.chip { display: inline-block; padding: 0 8px; border-radius: 10px; margin: 1px 0; font-size: 0.9em; }
.chip.pass { background: var(--pass-bg); }
.chip.fail { background: #ffcecb; }
details { margin: 8px 0; }
details > summary { cursor: pointer; color: var(--link); }
pre { background: var(--head); border: 1px solid var(--border); border-radius: 6px; padding: 10px 12px;
  overflow: auto; font-size: 0.82em; max-height: 480px; }
.failure { background: var(--fail-bg); border-left: 4px solid var(--fail); padding: 8px 12px; margin: 8px 0; border-radius: 4px; }
.failure pre { background: #fff; margin: 6px 0 0; }
figure { margin: 14px 0; }
figure img { max-width: 100%; height: auto; border: 1px solid var(--border); border-radius: 4px; display: block; }
.renders { display: grid; grid-template-columns: repeat(auto-fill, minmax(340px, 1fr)); gap: 16px; }
.renders figure { margin: 0; }
.renders video { width: 100%; margin-top: 6px; background: #000; border-radius: 4px; }
.plot-block { margin: 10px 0 22px; }
.tofu-plot { position: relative; border: 1px solid var(--border); border-radius: 6px; padding: 6px 8px 4px; background: #fff; }
.plot-bar { display: flex; justify-content: space-between; align-items: center; gap: 10px; flex-wrap: wrap; font-size: 0.85em; }
.plot-bar button { font: inherit; border: 1px solid var(--border); background: var(--head); border-radius: 12px; padding: 1px 9px; cursor: pointer; margin: 2px 4px 2px 0; }
.plot-bar button.series.off { opacity: 0.35; text-decoration: line-through; }
.swatch { display: inline-block; width: 16px; height: 0; border-top: 3px solid; vertical-align: middle; margin-right: 5px; }
.swatch.dashed { border-top-style: dashed; }
.plot-canvas { display: block; width: 100%; height: 340px; cursor: crosshair; touch-action: none; }
.plot-tip { position: absolute; display: none; pointer-events: none; z-index: 5; background: rgba(255, 255, 255, 0.96);
  border: 1px solid #8c959f; border-radius: 5px; padding: 5px 9px; font-size: 12px; white-space: nowrap;
  box-shadow: 0 2px 8px rgba(0, 0, 0, 0.15); }
.plot-tip .tip-time { font-weight: 700; margin-bottom: 2px; }
.plot-tip .tip-band { color: var(--fail); }
.plot-help { color: var(--muted); font-size: 0.8em; padding: 2px 0; }
footer { max-width: 1280px; margin: 0 auto; padding: 14px 32px 30px; color: var(--muted); font-size: 0.82em; border-top: 1px solid var(--border); }
)CSS";

// Plain ES5-style script (no modules, no build step): Debian's chromium and any CI
// artifact viewer run it as it is.
const char* const kPlotScript = R"JS(
(function () {
  'use strict';
  function niceStep(span, count) {
    var raw = span / Math.max(count, 1);
    var p = Math.pow(10, Math.floor(Math.log10(raw)));
    var f = raw / p;
    return (f < 1.5 ? 1 : f < 3.5 ? 2 : f < 7.5 ? 5 : 10) * p;
  }
  function fmt(v) {
    if (v === null || v === undefined || !isFinite(v)) return 'n/a';
    var a = Math.abs(v);
    if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(2);
    var s = v.toPrecision(4);
    if (s.indexOf('.') >= 0 && s.indexOf('e') < 0) s = s.replace(/0+$/, '').replace(/\.$/, '');
    return s;
  }
  function tickText(v, step) {
    var digits = Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
    return v.toFixed(digits);
  }
  function lowerBound(a, x) {
    var lo = 0, hi = a.length;
    while (lo < hi) { var m = (lo + hi) >> 1; if (a[m] < x) lo = m + 1; else hi = m; }
    return lo;
  }
  function isValue(v) { return v !== null && v !== undefined && isFinite(v); }

  function Plot(root) {
    var spec = JSON.parse(root.querySelector('script.plot-data').textContent);
    var canvas = root.querySelector('canvas');
    var tip = root.querySelector('.plot-tip');
    var logBox = root.querySelector('input.plot-log');
    var rangeText = root.querySelector('.plot-range');
    var ctx = canvas.getContext('2d');
    var series = spec.series || [];
    var bands = spec.bands || [];
    var t0 = Infinity, t1 = -Infinity;
    series.forEach(function (s) {
      s.on = true;
      if (s.t.length) { t0 = Math.min(t0, s.t[0]); t1 = Math.max(t1, s.t[s.t.length - 1]); }
    });
    if (!isFinite(t0)) { t0 = 0; t1 = 1; }
    if (t1 <= t0) t1 = t0 + 1;
    var full = [t0, t1], view = [t0, t1];
    var pad = { l: 66, r: 18, t: 12, b: 44 };
    var hover = null, drag = null, geo = null;

    function logScale() { return !!(logBox && logBox.checked); }
    function indexRange(s) { return [Math.max(lowerBound(s.t, view[0]) - 1, 0), Math.min(lowerBound(s.t, view[1]) + 1, s.t.length)]; }
    function yRange() {
      var lo = Infinity, hi = -Infinity, log = logScale();
      series.forEach(function (s) {
        if (!s.on) return;
        var r = indexRange(s);
        for (var i = r[0]; i < r[1]; i++) {
          var v = s.y[i];
          if (!isValue(v) || (log && v <= 0)) continue;
          if (v < lo) lo = v;
          if (v > hi) hi = v;
        }
      });
      if (!isFinite(lo)) { lo = log ? 0.01 : 0; hi = log ? 1 : 1; }
      if (log) {
        lo = Math.log10(lo); hi = Math.log10(hi);
        if (hi - lo < 0.3) { lo -= 0.15; hi += 0.15; }
        var m = (hi - lo) * 0.05;
        return [lo - m, hi + m];
      }
      if (spec.y_from_zero !== false) lo = Math.min(0, lo);
      if (hi - lo < 1e-12) { hi = lo + (Math.abs(lo) > 0 ? Math.abs(lo) * 0.1 : 1); }
      var margin = (hi - lo) * 0.06;
      return [spec.y_from_zero !== false && lo === 0 ? 0 : lo - margin, hi + margin];
    }
    function draw() {
      var rect = canvas.getBoundingClientRect();
      var dpr = window.devicePixelRatio || 1;
      var w = Math.max(rect.width, 240), h = Math.max(rect.height, 160);
      if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
        canvas.width = Math.round(w * dpr);
        canvas.height = Math.round(h * dpr);
      }
      ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
      ctx.fillStyle = '#fff';
      ctx.fillRect(0, 0, w, h);
      var pw = w - pad.l - pad.r, ph = h - pad.t - pad.b;
      var log = logScale(), yr = yRange();
      function X(t) { return pad.l + (t - view[0]) / (view[1] - view[0]) * pw; }
      function Y(v) { var u = log ? Math.log10(v) : v; return pad.t + ph - (u - yr[0]) / (yr[1] - yr[0]) * ph; }
      geo = { w: w, h: h, pw: pw, ph: ph, X: X, Y: Y };
      ctx.font = '11px system-ui, sans-serif';
      // Fault windows behind everything.
      bands.forEach(function (b) {
        var a = Math.max(b.t0, view[0]), c = Math.min(b.t1, view[1]);
        if (c <= a) return;
        ctx.fillStyle = 'rgba(207, 34, 46, 0.08)';
        ctx.fillRect(X(a), pad.t, Math.max(X(c) - X(a), 1), ph);
        ctx.fillStyle = 'rgba(207, 34, 46, 0.8)';
        ctx.textAlign = 'left'; ctx.textBaseline = 'top';
        if (X(c) - X(a) > 40) ctx.fillText(b.label, X(a) + 3, pad.t + 2);
      });
      // Grid and ticks.
      ctx.lineWidth = 1;
      ctx.strokeStyle = '#eaeef2';
      ctx.fillStyle = '#59636e';
      var xs = niceStep(view[1] - view[0], Math.max(2, Math.floor(pw / 90)));
      ctx.textAlign = 'center'; ctx.textBaseline = 'top';
      for (var tx = Math.ceil(view[0] / xs) * xs; tx <= view[1] + xs * 1e-6; tx += xs) {
        var px = Math.round(X(tx)) + 0.5;
        ctx.beginPath(); ctx.moveTo(px, pad.t); ctx.lineTo(px, pad.t + ph); ctx.stroke();
        ctx.fillText(tickText(tx, xs), px, pad.t + ph + 5);
      }
      ctx.textAlign = 'right'; ctx.textBaseline = 'middle';
      var yTick = function (u, text) {
        var py = Math.round(pad.t + ph - (u - yr[0]) / (yr[1] - yr[0]) * ph) + 0.5;
        ctx.beginPath(); ctx.moveTo(pad.l, py); ctx.lineTo(pad.l + pw, py); ctx.stroke();
        ctx.fillText(text, pad.l - 6, py);
      };
      if (log) {
        var mantissas = yr[1] - yr[0] < 2.5 ? [1, 2, 5] : [1];
        for (var d = Math.floor(yr[0]); d <= Math.ceil(yr[1]); d++) {
          mantissas.forEach(function (m) {
            var u = d + Math.log10(m);
            if (u >= yr[0] && u <= yr[1]) yTick(u, fmt(Math.pow(10, u)));
          });
        }
      } else {
        var ys = niceStep(yr[1] - yr[0], Math.max(2, Math.floor(ph / 45)));
        for (var v = Math.ceil(yr[0] / ys) * ys; v <= yr[1] + ys * 1e-6; v += ys) yTick(v, tickText(v, ys));
      }
      ctx.strokeStyle = '#8c959f';
      ctx.strokeRect(pad.l + 0.5, pad.t + 0.5, pw, ph);
      ctx.fillStyle = '#1f2328';
      ctx.font = '12px system-ui, sans-serif';
      ctx.textAlign = 'center'; ctx.textBaseline = 'bottom';
      ctx.fillText('time [s]', pad.l + pw / 2, h - 4);
      ctx.save();
      ctx.translate(14, pad.t + ph / 2); ctx.rotate(-Math.PI / 2);
      ctx.textBaseline = 'middle';
      ctx.fillText(spec.y_label || '', 0, 0);
      ctx.restore();
      // The series, clipped to the frame; a line breaks where samples are missing.
      ctx.save();
      ctx.beginPath(); ctx.rect(pad.l, pad.t, pw, ph); ctx.clip();
      series.forEach(function (s) {
        if (!s.on || !s.t.length) return;
        ctx.strokeStyle = s.color; ctx.lineWidth = 1.5;
        ctx.setLineDash(s.dash ? [6, 4] : []);
        var r = indexRange(s), gap = s.gap_s || Infinity, pen = false, prev = 0;
        ctx.beginPath();
        for (var i = r[0]; i < r[1]; i++) {
          var y = s.y[i];
          if (!isValue(y) || (log && y <= 0)) { pen = false; continue; }
          if (pen && s.t[i] - prev > gap) pen = false;
          var qx = X(s.t[i]), qy = Y(y);
          if (pen) ctx.lineTo(qx, qy); else ctx.moveTo(qx, qy);
          pen = true; prev = s.t[i];
        }
        ctx.stroke();
      });
      ctx.setLineDash([]);
      if (drag && Math.abs(drag.x1 - drag.x0) > 2) {
        ctx.fillStyle = 'rgba(9, 105, 218, 0.13)';
        ctx.fillRect(Math.min(drag.x0, drag.x1), pad.t, Math.abs(drag.x1 - drag.x0), ph);
      }
      if (hover) {
        var hx = Math.round(X(hover.t)) + 0.5;
        ctx.strokeStyle = 'rgba(31, 35, 40, 0.5)';
        ctx.beginPath(); ctx.moveTo(hx, pad.t); ctx.lineTo(hx, pad.t + ph); ctx.stroke();
        hover.rows.forEach(function (row) {
          if (log && row.v <= 0) return;
          ctx.fillStyle = row.s.color;
          ctx.beginPath(); ctx.arc(X(row.t), Y(row.v), 3.5, 0, 2 * Math.PI); ctx.fill();
        });
      }
      ctx.restore();
      if (rangeText) {
        var zoomed = view[0] > full[0] || view[1] < full[1];
        rangeText.textContent = zoomed ? 'Showing ' + fmt(view[0]) + '–' + fmt(view[1]) + ' s of ' +
          fmt(full[0]) + '–' + fmt(full[1]) + ' s.' : '';
      }
    }
    function tAt(x) { return view[0] + (x - pad.l) / geo.pw * (view[1] - view[0]); }
    function local(e) { var r = canvas.getBoundingClientRect(); return { x: e.clientX - r.left, y: e.clientY - r.top }; }
    function inFrame(p) { return geo && p.x >= pad.l && p.x <= pad.l + geo.pw && p.y >= pad.t && p.y <= pad.t + geo.ph; }
    function rowsAt(t) {
      var rows = [];
      series.forEach(function (s) {
        if (!s.on || !s.t.length) return;
        var i = Math.min(lowerBound(s.t, t), s.t.length - 1);
        if (i > 0 && Math.abs(s.t[i - 1] - t) < Math.abs(s.t[i] - t)) i--;
        if (Math.abs(s.t[i] - t) > (s.gap_s || Infinity) || !isValue(s.y[i])) return;
        rows.push({ s: s, t: s.t[i], v: s.y[i] });
      });
      return rows;
    }
    function showTip(p) {
      var t = tAt(p.x);
      hover = { t: t, rows: rowsAt(t) };
      tip.textContent = '';
      var head = document.createElement('div');
      head.className = 'tip-time';
      head.textContent = 't = ' + fmt(t) + ' s';
      tip.appendChild(head);
      hover.rows.forEach(function (row) {
        var line = document.createElement('div');
        var sw = document.createElement('span');
        sw.className = 'swatch' + (row.s.dash ? ' dashed' : '');
        sw.style.borderColor = row.s.color;
        line.appendChild(sw);
        line.appendChild(document.createTextNode(row.s.name + ': ' + fmt(row.v) + (spec.unit ? ' ' + spec.unit : '')));
        tip.appendChild(line);
      });
      if (!hover.rows.length) {
        var none = document.createElement('div');
        none.textContent = 'no sample here';
        tip.appendChild(none);
      }
      bands.forEach(function (b) {
        if (t < b.t0 || t > b.t1) return;
        var line = document.createElement('div');
        line.className = 'tip-band';
        line.textContent = 'fault: ' + b.label;
        tip.appendChild(line);
      });
      tip.style.display = 'block';
      var left = canvas.offsetLeft + p.x + 16;
      if (p.x + 16 + tip.offsetWidth > geo.w) left = canvas.offsetLeft + p.x - 16 - tip.offsetWidth;
      tip.style.left = Math.max(0, left) + 'px';
      tip.style.top = Math.max(0, canvas.offsetTop + p.y - 12) + 'px';
    }
    function hideTip() { hover = null; tip.style.display = 'none'; }
    function setView(a, b) {
      var whole = full[1] - full[0], least = whole * 1e-4;
      if (b - a < least) { var c = (a + b) / 2; a = c - least / 2; b = c + least / 2; }
      if (b - a >= whole) { a = full[0]; b = full[1]; }
      if (a < full[0]) { b += full[0] - a; a = full[0]; }
      if (b > full[1]) { a -= b - full[1]; b = full[1]; }
      view = [Math.max(a, full[0]), Math.min(b, full[1])];
      draw();
    }
    canvas.addEventListener('mousemove', function (e) {
      var p = local(e);
      if (drag) drag.x1 = Math.max(pad.l, Math.min(p.x, pad.l + geo.pw));
      if (inFrame(p)) showTip(p); else hideTip();
      draw();
    });
    canvas.addEventListener('mouseleave', function () { hideTip(); draw(); });
    canvas.addEventListener('mousedown', function (e) {
      var p = local(e);
      if (e.button !== 0 || !inFrame(p)) return;
      drag = { x0: p.x, x1: p.x };
      e.preventDefault();
    });
    window.addEventListener('mouseup', function () {
      if (!drag) return;
      var a = Math.min(drag.x0, drag.x1), b = Math.max(drag.x0, drag.x1);
      drag = null;
      if (b - a > 4) setView(tAt(a), tAt(b)); else draw();
    });
    canvas.addEventListener('wheel', function (e) {
      var p = local(e);
      if (!inFrame(p)) return;
      e.preventDefault();
      var factor = Math.exp((e.deltaY > 0 ? 1 : -1) * 0.2), tc = tAt(p.x);
      setView(tc - (tc - view[0]) * factor, tc + (view[1] - tc) * factor);
    }, { passive: false });
    canvas.addEventListener('dblclick', function () { setView(full[0], full[1]); });
    var reset = root.querySelector('.plot-reset');
    if (reset) reset.addEventListener('click', function () { setView(full[0], full[1]); });
    if (logBox) logBox.addEventListener('change', draw);
    Array.prototype.forEach.call(root.querySelectorAll('button.series'), function (button) {
      button.addEventListener('click', function () {
        var s = series[Number(button.getAttribute('data-i'))];
        if (!s) return;
        s.on = !s.on;
        button.classList.toggle('off', !s.on);
        draw();
      });
    });
    window.addEventListener('resize', draw);
    draw();
    root.setAttribute('data-ready', '1');
  }
  Array.prototype.forEach.call(document.querySelectorAll('.tofu-plot'), function (root) {
    try { Plot(root); } catch (err) {
      var note = document.createElement('p');
      note.className = 'failure';
      note.textContent = 'This plot could not be drawn: ' + err;
      root.appendChild(note);
      throw err;
    }
  });
})();
)JS";

}  // namespace tofu::report
