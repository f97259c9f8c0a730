"""Small pieces of page behaviour that viser has no API for, injected once as HTML.

- Keys pressed on a focused control (slider thumb, button, tab, field) stay with that control:
  viser's 3D view moves its camera on arrow keys / WASD seen by ``document``; a listener on
  ``body`` stops those events after the control has handled them.
- Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y (outside text fields) click the Undo / Redo buttons.

viser renders ``add_html`` content with ``innerHTML``, where a ``<script>`` never runs; an
``<img onerror>`` handler does, so the script hangs off a tiny broken image. It installs its
listeners once per page, whatever number of times the element is rendered.
"""

from __future__ import annotations

import html

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
}
"""

#: HTML that installs the key handling when rendered (invisible).
KEY_HANDLING_HTML = (
    '<img src="data:," alt="" style="display:none" onerror="'
    + html.escape(" ".join(_SCRIPT.split()), quote=True)
    + '">'
)


def hide_slider_boxes(uuids: list[str]) -> str:
    """CSS that hides the number box viser puts beside these sliders (their exact fields replace it)."""
    selectors = ", ".join(f"[id='{u}'] + *" for u in uuids)
    return f"<style>{selectors} {{ display: none !important; }}</style>" if uuids else ""
