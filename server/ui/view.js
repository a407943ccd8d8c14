// What the views share: the source documents' codes in their words, values formatted and
// parsed, badges for a link's and a device's state, table heads.

import { h } from './dom.js';

// Source document 000's error codes, in its words.
export const LINK_CODES = {
  0: 'OK — port is open',
  1: 'No port configured (port string is empty)',
  2: 'Port open failed (device doesn’t exist, permission denied, or busy)',
  3: 'Port lost (was open, now disconnected)',
};
export const DEVICE_CODES = {
  0: 'OK — device is responding',
  1: 'No link configured (link string is empty)',
  2: 'No slave configured (slave_id is 0)',
  10: 'Communication error (timeout, CRC mismatch, or device not responding)',
};
// Seed 002's transaction states.
export const TRANSACTION_STATES = {
  0: 'not run yet',
  4: 'done',
  [-1]: 'interface unavailable',
  [-2]: 'response timeout',
  [-3]: 'unknown error',
};
export const NUMERIC = new Set(['SINT', 'INT', 'DINT', 'LINT', 'USINT', 'UINT', 'UDINT', 'ULINT',
  'BYTE', 'WORD', 'DWORD', 'LWORD', 'REAL', 'LREAL']);
export const TREND_POINTS = 60;
export const REFRESH_MS = 2000;

export function formatValue(type, value) {
  if (value === null || value === undefined) return '—';
  if (type === 'BOOL') return value ? 'TRUE' : 'FALSE';
  if (type === 'REAL' || type === 'LREAL') {
    return Number.isInteger(value) ? String(value) : String(Number(value.toPrecision(7)));
  }
  if (type === 'TIME') return `${value} ms`;
  return String(value);
}

export function percent(ratio) {
  return ratio === undefined || ratio === null ? '—' : `${(ratio * 100).toFixed(1)} %`;
}

/** A typed value from what was typed: the API checks it and names what is wrong. */
export function parseInput(type, raw) {
  const t = raw.trim();
  if (type === 'STRING') return raw;
  if (type === 'BOOL') {
    if (/^(true|1|on)$/i.test(t)) return true;
    if (/^(false|0|off)$/i.test(t)) return false;
    return t;
  }
  if (/^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$/.test(t)) return Number(t);
  return t;
}

export const enc = encodeURIComponent;

/** A link or device that is connected with error code 0. */
export function healthy(x) {
  return x.connected && x.error_code === 0;
}

/** A table head with these column names. */
export function head(...names) {
  return h('thead', {}, h('tr', {}, ...names.map((c) => h('th', { scope: 'col' }, c))));
}

/** Calls `load` the first time `details` is opened. */
export function loadOnOpen(details, load) {
  details.addEventListener('toggle', () => {
    if (!details.open || details.dataset.loaded) return;
    details.dataset.loaded = '1';
    load();
  });
  return details;
}

export function linkState(link) {
  const ok = healthy(link);
  return h('span', { class: `badge ${ok ? 'ok' : 'bad'}` },
    ok ? 'connected' : `error ${link.error_code}`);
}

export function deviceState(d) {
  const ok = healthy(d);
  return h('span', { class: `badge ${ok ? 'ok' : 'bad'}`, 'data-state': ok ? 'connected' : 'disconnected' },
    ok ? 'connected' : `disconnected · error ${d.error_code}`);
}

export function endpointOf(l) {
  if (l.kind === 'serial') {
    return `${l.port} · ${l.baud} ${l.data_bits}${l.parity}${l.stop_bits}${l.framing === 'ascii' ? ' · ASCII' : ''}`;
  }
  if (l.kind === 'tcp') return `${l.host}:${l.tcp_port} (${l.framing})`;
  return `${l.kind} ${l.endpoint}`;
}
