// Building the page from elements and text nodes only: no HTML strings anywhere.

const SVG = 'http://www.w3.org/2000/svg';

function append(el, children) {
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    el.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return el;
}

function setAttrs(el, attrs) {
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key.startsWith('on') && typeof value === 'function') {
      el.addEventListener(key.slice(2), value);
    } else {
      el.setAttribute(key, value === true ? '' : String(value));
    }
  }
  return el;
}

/** An HTML element: `h('td', {class: 'x'}, 'text', child)`. */
export function h(tag, attrs, ...children) {
  return append(setAttrs(document.createElement(tag), attrs), children);
}

/** An SVG element. */
export function s(tag, attrs, ...children) {
  return append(setAttrs(document.createElementNS(SVG, tag), attrs), children);
}

/** Replaces the children of `el`. */
export function fill(el, ...children) {
  el.replaceChildren();
  return append(el, children);
}

/** Sets the text of `el` when it differs (keeps the DOM quiet). */
export function text(el, value) {
  const t = String(value);
  if (el.textContent !== t) el.textContent = t;
}

/** A small line chart of `values` (numbers), as an SVG polyline. */
export function sparkline(values, label) {
  const width = 120;
  const height = 28;
  const svg = s('svg', {
    class: 'spark', viewBox: `0 0 ${width} ${height}`, width, height,
    role: 'img', 'aria-label': label,
  });
  if (values.length < 2) return svg;
  let min = Math.min(...values);
  let max = Math.max(...values);
  if (max === min) { max += 1; min -= 1; }
  const step = width / (values.length - 1);
  const points = values.map((v, i) =>
    `${(i * step).toFixed(1)},${(height - 2 - ((v - min) / (max - min)) * (height - 4)).toFixed(1)}`);
  svg.append(s('polyline', { points: points.join(' ') }));
  return svg;
}
