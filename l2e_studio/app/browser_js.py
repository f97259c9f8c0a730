"""Small pieces of page behaviour that viser has no API for, injected once as HTML.

- Keys pressed on a focused control (slider thumb, button, tab, field) stay with that control:
  viser's 3D view moves its camera on arrow keys / WASD seen by ``document``; a listener on
  ``body`` stops those events after the control has handled them.
- Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y (outside text fields) click the Undo / Redo buttons.
- A click (or, where allowed, a drag) on an image that follows a :func:`pointer_marker` writes
  ``"fx, fy, stamp"`` (fractions of the image's width and height) into the text field the
  marker names; the server reads it from there (viser has no image click events).
- A click on a row of the scene table (first header cell "use") writes ``select:<scene>`` (or
  ``toggle:<scene>`` on the first cell) into the hidden "Scene pointer" field.
- The window's size (``"<width>x<height>"``) goes into the hidden "Window size" field once the
  page is up and after each resize, so that the server can give the overlay the space.

- In a browser that draws WebGL in software (no GPU: SwiftShader, llvmpipe), the 3D view is
  paused while the extrinsic or the display is tuned: every 3D frame there costs the page's
  main thread 50-150 ms (drawing and reading the canvas back), which would hold up the overlay
  frame of the next key press. A key or pointer press on a slider, a nudge / Undo / Redo button,
  a text field or a scene table row starts a pause; the view keeps its last picture (the canvas
  is drawn with ``preserveDrawingBuffer``: WebGL draw and clear calls are skipped, so the
  canvas is never redrawn nor read back) and catches up ``TUNE_PAUSE_MS`` after the last such
  press, or at once when the pointer enters the 3D view. With a GPU nothing is paused.
  ``window.__l2e3d`` holds the state (``soft``, ``drawn``, ``skipped``, ``paused()``).

viser renders ``add_html`` content with ``innerHTML``, where a ``<script>`` never runs; an
``<img onerror>`` handler does, so the script hangs off a tiny broken image. It installs its
listeners once per page, whatever number of times the element is rendered.
"""

from __future__ import annotations

import html

#: ms after the last tuning press that a software-drawn 3D view catches up (a person nudging
#: pauses 0.5-2 s between presses; the 3D view follows once they stop, or on hover)
TUNE_PAUSE_MS = 3000

_SCRIPT = r"""
if (!window.__l2eKeys) {
  window.__l2eKeys = true;
  const isText = (el) => el && (el.tagName === 'INPUT' || el.tagName === 'TEXTAREA' || el.isContentEditable);
  const onControl = (el) => el && el !== document.body && !(el.tagName === 'CANVAS');
  const clickButton = (label) => {
    const b = Array.from(document.querySelectorAll('button')).find(x => x.textContent.trim() === label);
    if (b && !b.disabled) b.click();
  };
  document.addEventListener('keydown', (e) => {
    const mod = e.ctrlKey || e.metaKey;
    if (!mod || isText(e.target)) return;
    const k = e.key.toLowerCase();
    if (k === 'z' && !e.shiftKey) { clickButton('Undo'); e.preventDefault(); }
    else if ((k === 'z' && e.shiftKey) || k === 'y') { clickButton('Redo'); e.preventDefault(); }
  }, true);
  for (const type of ['keydown', 'keyup']) {
    document.body.addEventListener(type, (e) => { if (onControl(e.target)) e.stopPropagation(); });
  }
  const setField = (label, text) => {
    const lab = Array.from(document.querySelectorAll('label')).find(l => l.textContent.trim() === label);
    const box = lab && lab.closest('.mantine-Flex-root');
    const input = box && box.querySelector('input');
    if (!input) return;
    Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, 'value').set.call(input, text);
    input.dispatchEvent(new Event('input', {bubbles: true}));
  };
  let lastMove = 0;
  const onPointer = (e, moving) => {
    const img = e.target;
    if (!(img instanceof HTMLImageElement) || !img.src.startsWith('blob:')) return;
    let marker = null;
    for (const m of document.querySelectorAll('[data-l2e-pointer]')) {
      if (m.compareDocumentPosition(img) & Node.DOCUMENT_POSITION_FOLLOWING) marker = m;
    }
    if (!marker || (moving && marker.dataset.drag !== '1')) return;
    const now = performance.now();
    if (moving && now - lastMove < 60) return;
    lastMove = now;
    const r = img.getBoundingClientRect();
    const fx = (e.clientX - r.left) / r.width, fy = (e.clientY - r.top) / r.height;
    setField(marker.dataset.l2ePointer, fx.toFixed(4) + ', ' + fy.toFixed(4) + ', ' + Math.round(now));
    e.preventDefault();
  };
  document.addEventListener('click', (e) => {
    const tr = e.target instanceof Element && e.target.closest('tbody tr');
    const table = tr && tr.closest('table');
    const head = table && table.querySelector('th');
    if (!head || head.textContent.trim() !== 'use' || tr.cells.length < 2) return;
    const action = e.target.closest('td') === tr.cells[0] ? 'toggle' : 'select';
    setField('Scene pointer', action + ':' + tr.cells[1].textContent.trim() + ',' + Math.round(performance.now()));
  }, true);
  const reportSize = (tries) => {
    const lab = Array.from(document.querySelectorAll('label')).find(l => l.textContent.trim() === 'Window size');
    if (!lab) { if (tries > 0) setTimeout(() => reportSize(tries - 1), 250); return; }
    setField('Window size', window.innerWidth + 'x' + window.innerHeight);
  };
  let sizeTimer = null;
  window.addEventListener('resize', () => { clearTimeout(sizeTimer); sizeTimer = setTimeout(() => reportSize(0), 300); });
  reportSize(40);
  const S = window.__l2e3d = {soft: false, drawn: 0, skipped: 0, until: 0,
                              paused: () => S.soft && performance.now() < S.until};
  try {
    const gl = document.createElement('canvas').getContext('webgl');
    const info = gl && gl.getExtension('WEBGL_debug_renderer_info');
    const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)).toLowerCase() : '';
    S.soft = /swiftshader|llvmpipe|softpipe|software/.test(name);
    const lose = gl && gl.getExtension('WEBGL_lose_context');
    if (lose) lose.loseContext();
  } catch (e) {}
  if (S.soft) {
    const calls = ['clear', 'drawArrays', 'drawElements', 'drawArraysInstanced', 'drawElementsInstanced',
                   'drawRangeElements', 'blitFramebuffer'];
    for (const ctx of [window.WebGLRenderingContext, window.WebGL2RenderingContext]) {
      if (!ctx) continue;
      for (const name of calls) {
        const f = ctx.prototype[name];
        if (typeof f !== 'function') continue;
        ctx.prototype[name] = function (...args) {
          if (S.paused()) { S.skipped++; return; }
          S.drawn++;
          return f.apply(this, args);
        };
      }
    }
  }
  const tuning = (el) => el instanceof Element && !!(el.closest('[role=slider], .mantine-Slider-root') ||
      el.tagName === 'INPUT' || el.tagName === 'TEXTAREA' ||
      /^([\u2212+]|Undo$|Redo$)/.test((el.closest('button') || {textContent: ''}).textContent.trim()) ||
      (el.closest('tbody tr') && (el.closest('table').querySelector('th') || {}).textContent === 'use'));
  const onInput = (e) => { if (e.target instanceof Element && e.target.tagName !== 'CANVAS') {
    S.until = tuning(e.target) ? performance.now() + TUNE_PAUSE_MS : 0; } };
  document.addEventListener('keydown', onInput, true);
  document.addEventListener('pointerdown', onInput, true);
  document.addEventListener('pointerover', (e) => { if (e.target instanceof HTMLCanvasElement) S.until = 0; }, true);
  document.addEventListener('pointerdown', (e) => onPointer(e, false), true);
  document.addEventListener('pointermove', (e) => { if (e.buttons & 1) onPointer(e, true); }, true);
  document.addEventListener('dragstart', (e) => { if (e.target instanceof HTMLImageElement) e.preventDefault(); }, true);
}
"""

#: HTML that installs the key handling when rendered (invisible).
KEY_HANDLING_HTML = (
    '<img src="data:," alt="" style="display:none" onerror="'
    + html.escape(" ".join(_SCRIPT.replace("TUNE_PAUSE_MS", str(TUNE_PAUSE_MS)).split()), quote=True)
    + '">'
)


def hide_slider_boxes(uuids: list[str]) -> str:
    """CSS that hides the number box viser puts beside these sliders (their exact fields replace it)."""
    selectors = ", ".join(f"[id='{u}'] + *" for u in uuids)
    return f"<style>{selectors} {{ display: none !important; }}</style>" if uuids else ""


def pointer_marker(field_label: str, drag: bool = False) -> str:
    """An invisible marker: clicks on the next image go to the text field labelled ``field_label``."""
    return (f"<span data-l2e-pointer='{html.escape(field_label, quote=True)}' data-drag='{1 if drag else 0}'></span>"
            + KEY_HANDLING_HTML)


def hide_inputs(handles: list) -> str:
    """CSS that hides these viser inputs (label and field), e.g. the pointer fields."""
    rules = []
    for h in handles:
        u = h._impl.uuid
        rules.append(f"div:has(> div > div > p > label[for='{u}']), div:has(> div > p > label[for='{u}'])")
    return "<style>" + ", ".join(rules) + " { display: none !important; }</style>" if rules else ""
