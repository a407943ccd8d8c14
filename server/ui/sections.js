// The overview's sections beside links and devices: the servers listening, the Modbus
// server's serial ports, MQTT, and the configuration in force.

import { api } from './api.js';
import { h } from './dom.js';

export function age(timestamp) {
  if (!timestamp) return '—';
  const seconds = (Date.now() - Date.parse(timestamp)) / 1000;
  if (!Number.isFinite(seconds)) return '—';
  if (seconds < 1) return '< 1 s';
  if (seconds < 60) return `${Math.floor(seconds)} s`;
  if (seconds < 3600) return `${Math.floor(seconds / 60)} min`;
  return `${Math.floor(seconds / 3600)} h`;
}

/** How long ago `timestamp` was, or 'not yet'. */
export function ago(timestamp) {
  return timestamp ? `${age(timestamp)} ago` : 'not yet';
}

export function cell(label, ...children) {
  return h('td', { 'data-label': label }, ...children);
}

/** The MQTT front-end's state (GET /api/v1/mqtt), or null when none is configured (then
 * /readyz has no `mqtt` detail, and the page does not ask for what would be a 404). */
export async function mqttStatus(signal) {
  const ready = await fetch('/readyz', { signal }).then((r) => r.json()).catch(() => null);
  if (!ready?.mqtt) return null;
  return api('GET', '/mqtt', undefined, { signal });
}

export function mqttRows(m) {
  const b = m.buffer;
  const sp = m.sparkplug;
  const rows = [
    ['Broker', m.broker, `client id ${m.client_id}`],
    ['State', h('span', { class: `badge ${m.connected ? 'ok' : 'bad'}`, 'data-state': m.connected ? 'connected' : 'disconnected' },
      m.connected ? 'connected' : 'disconnected'), m.last_error ?? `${m.reconnects} reconnect${m.reconnects === 1 ? '' : 's'}`],
    ['Messages', `${m.messages_out} out · ${m.messages_in} in`, `${m.bytes_out} bytes out`],
    ['Buffer', `${b.messages} waiting${b.messages ? `, oldest ${b.oldest_age_s} s` : ''}`,
      `${b.replayed} replayed · ${b.dropped} dropped${b.dir ? '' : ' · no buffer on disk'}`],
    ['Writes', `${m.writes_accepted} accepted · ${m.writes_refused} refused`, ''],
  ];
  if (m.json_prefix) rows.push(['JSON topics', `${m.json_prefix}/…`, '']);
  if (sp) {
    const host = sp.primary_host ? `host ${sp.primary_host} ${sp.host_online === true ? 'online' : sp.host_online === false ? 'offline' : 'not seen yet'}` : 'no primary host';
    rows.push(['Sparkplug B', `spBv1.0/${sp.group_id}/…/${sp.edge_node_id}`,
      `${sp.born ? `born, ${sp.born_devices} device${sp.born_devices === 1 ? '' : 's'}` : 'not born'} · bdSeq ${sp.bd_seq} · ${sp.rebirths} rebirths · ${host}`]);
  }
  return rows.map(([label, value, meaning]) => h('tr', { 'data-mqtt': label },
    h('th', { scope: 'row' }, label), cell(label, value, h('div', { class: 'meaning' }, meaning))));
}

/** The Modbus server's serial ports (GET /api/v1/map), or null when it has none (then
 * /readyz has no `modbus_serial` detail, and the page does not ask). */
export async function serialStatus(signal) {
  const ready = await fetch('/readyz', { signal }).then((r) => r.json()).catch(() => null);
  if (!ready?.modbus_serial) return null;
  return api('GET', '/map', undefined, { signal }).then((m) => m.serial).catch(() => null);
}

const SERIAL_MEANING = {
  open: 'answering masters',
  opening: 'not open yet',
  lost: 'failed; reopened every second',
};

export function serialRows(ports) {
  return ports.map((p) => {
    const f = p.frames;
    const ignored = f.other_unit + f.crc_error + f.malformed;
    return h('tr', { class: p.state === 'open' ? '' : 'problem', 'data-serial': p.port },
      cell('Port', h('strong', {}, p.port), h('div', { class: 'meaning' }, `${p.framing.toUpperCase()} ${p.line}`)),
      cell('Unit id', String(p.unit_id)),
      cell('State', h('span', { class: `badge ${p.state === 'open' ? 'ok' : 'bad'}`, 'data-state': p.state }, p.state),
        h('div', { class: 'meaning' }, p.error ?? `${SERIAL_MEANING[p.state] ?? ''}${p.reopens ? ` · reopened ${plural(p.reopens, 'time')}` : ''}`)),
      cell('Frames', `${f.answered} answered · ${f.exception} exceptions · ${f.broadcast} broadcasts`,
        h('div', { class: 'meaning' }, `${ignored} ignored (${f.other_unit} other units, ${f.crc_error} bad checksums, ${f.malformed} malformed)`)));
  });
}

/** The configuration in force and the last reload (GET /api/v1/config). */
export async function configStatus(signal) {
  return api('GET', '/config', undefined, { signal }).catch(() => null);
}

export function plural(n, word) {
  return `${n} ${word}${n === 1 ? '' : 's'}`;
}

/** The configuration's file, hash, load time and watch, and the last reload's report. Each
 * row's header names it, so its cell carries no label of its own (on a phone the card would
 * say the name twice). */
export function configRows(c) {
  const loaded = c.loaded_at_unix_ms ? new Date(c.loaded_at_unix_ms).toISOString() : null;
  const rows = [
    h('tr', { 'data-config': 'File' }, h('th', { scope: 'row' }, 'File'),
      cell('', c.file, h('div', { class: 'meaning' }, c.profiles ? `profiles in ${c.profiles}` : ''))),
  ];
  if (!c.hash) return rows;
  rows.push(h('tr', { 'data-config': 'Loaded' }, h('th', { scope: 'row' }, 'Loaded'),
    cell('', ago(loaded), h('div', { class: 'meaning' },
      `sha256 ${c.hash.slice(0, 12)} · ${c.watch ? 'files watched' : 'reloaded on SIGHUP or request'}`))));
  const r = c.last_report;
  const problems = c.last_problems ?? [];
  if (problems.length) {
    rows.push(h('tr', { class: 'problem', 'data-config': 'Refused' }, h('th', { scope: 'row' }, 'Refused'),
      cell('', h('span', { class: 'badge bad' }, 'last reload refused: nothing changed'),
        h('ul', { class: 'problems' }, ...problems.map((p) => h('li', {}, p))))));
  }
  if (r) {
    const when = new Date(r.at_unix_ms).toISOString();
    const changes = r.changes ?? [];
    const reopened = r.reopened ?? [];
    rows.push(h('tr', { 'data-config': 'Last reload' }, h('th', { scope: 'row' }, 'Last reload'),
      cell('',
        `${plural(changes.length, 'change')} (${r.trigger}), ${ago(when)}`,
        h('div', { class: 'meaning' }, `took ${r.took_ms} ms${reopened.length ? ` · reopened ${reopened.join(', ')}` : ''}`),
        h('ul', { class: 'changes' }, ...changes.map((x) => h('li', { 'data-change': `${x.kind} ${x.name}` },
          h('span', { class: `badge ${x.action === 'removed' ? 'bad' : 'ok'}` }, x.action), ' ',
          `${x.kind} `, h('strong', {}, x.name),
          x.details?.length ? h('div', { class: 'meaning' }, x.details.join('; ')) : null))))));
  }
  return rows;
}

const SERVERS = {
  http: ['REST API and web page', (a) => `${a}/ui · ${a}/api/v1/devices · events, /metrics`],
  grpc: ['gRPC', () => 'iogate.v1.Gateway, reflection and health (iogatectl, grpcurl)'],
  modbus: ['Modbus TCP server', () => 'every field at an IEC located address (iogate map prints them)'],
  opcua: ['OPC UA server', () => 'the devices under Objects/iogate'],
};

/** The servers listening now and how a client reaches each, the web page's own first. */
export function serverRows(listening) {
  const order = Object.keys(SERVERS);
  const rank = (l) => (order.includes(l.server) ? order.indexOf(l.server) : order.length);
  return [...listening].sort((a, b) => rank(a) - rank(b)).map((l) => {
    const [name, meaning] = SERVERS[l.server] ?? [l.server, () => ''];
    return h('tr', { 'data-server': l.server },
      h('th', { scope: 'row' }, name),
      cell('', h('code', {}, l.address), h('div', { class: 'meaning' }, meaning(l.address))));
  });
}
