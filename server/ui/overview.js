// The overview: every link and device live (states as events come, counters every two
// seconds), the servers listening, the Modbus server's serial ports, MQTT, standing
// transactions and the configuration in force.

import { api } from './api.js';
import { h, fill, text } from './dom.js';
import { ago, cell, mqttStatus, mqttRows, serialStatus, serialRows, configStatus, configRows, serverRows } from './sections.js';
import { main, follow } from './connection.js';
import {
  LINK_CODES, DEVICE_CODES, TRANSACTION_STATES, REFRESH_MS, enc, healthy, head, percent,
  linkState, deviceState, endpointOf,
} from './view.js';

/** A titled section around a table (`columns` its head, when it has one); the section
 * has `id` when given, the table `tableId`. */
function tableSection(key, title, columns, { id, tableId } = {}) {
  const body = h('tbody');
  const table = h('table', { class: 'list', id: tableId }, columns ? head(...columns) : null, body);
  const section = h('section', { 'aria-labelledby': `${key}-title`, id },
    h('h2', { id: `${key}-title` }, title), h('div', { class: 'scroll' }, table));
  return { section, body };
}

/** The status sections (serial ports, configuration and servers, MQTT), each hidden while
 * the gateway has none, and what shows a fresh status in them. */
function statusSections() {
  const serial = tableSection('serial', 'Modbus server on serial lines', ['Port', 'Unit id', 'State', 'Frames'],
    { id: 'serial' });
  const config = tableSection('config', 'Configuration', null, { id: 'config' });
  const servers = tableSection('servers', 'Servers', null, { id: 'servers' });
  const mqtt = tableSection('mqtt', 'MQTT', null, { id: 'mqtt' });
  servers.section.hidden = true;
  function render(ports, m, c) {
    serial.section.hidden = !ports;
    if (ports) fill(serial.body, ...serialRows(ports));
    mqtt.section.hidden = !m;
    if (m) fill(mqtt.body, ...mqttRows(m));
    config.section.hidden = !c;
    if (c) fill(config.body, ...configRows(c));
    servers.section.hidden = !c?.listening?.length;
    if (c?.listening) fill(servers.body, ...serverRows(c.listening));
  }
  return { serial: serial.section, config: config.section, servers: servers.section, mqtt: mqtt.section, render };
}

/** The links' table over `linksByName`. */
function linkRows(linkBody, linksByName) {
  fill(linkBody, ...[...linksByName.values()].map((l) => {
    const over = (l.planned_utilisation ?? 0) > 0.9 || (l.utilisation ?? 0) > 0.9;
    return h('tr', { class: healthy(l) ? '' : 'problem', 'data-link': l.name },
      cell('Link', h('a', { href: `#/links/${enc(l.name)}` }, h('strong', {}, l.name))),
      cell('Endpoint', endpointOf(l)),
      cell('State', linkState(l), h('div', { class: 'meaning' }, LINK_CODES[l.error_code] ?? '')),
      cell('Utilisation', h('span', { class: over ? 'warn' : '' },
        `${percent(l.utilisation)} measured`), h('div', { class: 'meaning' }, `${percent(l.planned_utilisation)} planned`)),
      cell('Devices', String(l.devices.length)));
  }));
  if (!linksByName.size) linkBody.append(h('tr', {}, h('td', { colspan: 5, class: 'muted' }, 'No links: simulated devices only.')));
}

/** A device's row, and what updates it with fresh diagnostics. */
function deviceRow(d) {
  const state = h('td', { 'data-label': 'State' });
  const cycles = cell('I/O cycles');
  const response = cell('Last response');
  const row = h('tr', { 'data-device': d.name },
    cell('Device', h('a', { href: `#/devices/${enc(d.name)}` }, d.name)),
    cell('Profile', d.profile),
    cell('Link', d.link ?? (d.protocol === 'simulated' ? 'simulated' : '—')),
    state, cycles, response);
  const update = (diag) => {
    row.classList.toggle('problem', !healthy(diag));
    fill(state, deviceState(diag), h('div', { class: 'meaning' }, DEVICE_CODES[diag.error_code] ?? ''));
    text(cycles, diag.io_cycles);
    text(response, `${Number(diag.last_response_ms).toFixed(1)} ms`);
  };
  update(d);
  return { row, update };
}

/** The count of links and devices, and how many are down. */
function summaryBadges(summary, linksByName, devicesByName) {
  const linksDown = [...linksByName.values()].filter((l) => !healthy(l)).length;
  const devicesDown = [...devicesByName.values()].filter((d) => !healthy(d)).length;
  fill(summary,
    h('span', { class: `badge ${linksDown ? 'bad' : 'ok'}` },
      `${linksByName.size} link${linksByName.size === 1 ? '' : 's'}${linksDown ? `, ${linksDown} down` : ''}`),
    ' ',
    h('span', { class: `badge ${devicesDown ? 'bad' : 'ok'}` },
      `${devicesByName.size} device${devicesByName.size === 1 ? '' : 's'}${devicesDown ? `, ${devicesDown} not answering` : ''}`));
}

/** The standing transactions' rows. */
function transactionRows(transactionBody, transactions) {
  fill(transactionBody, ...[...transactions.values()].map((t) => {
    const good = t.state === 4 || t.state === 0;
    return h('tr', { class: good ? '' : 'problem', 'data-transaction': t.name },
      cell('Name', h('strong', {}, t.name)), cell('Link', t.link), cell('Kind', t.kind),
      cell('State', h('span', { class: `badge ${good ? 'ok' : 'bad'}` },
        `${t.state} ${TRANSACTION_STATES[t.state] ?? ''}`),
      t.error ? h('div', { class: 'meaning' }, t.error) : null),
      cell('Value', t.value ?? '—'), cell('Runs', String(t.runs)), cell('Failures', String(t.failures)),
      cell('Last run', ago(t.timestamp)));
  }));
}

/** What the overview holds: links and devices by name, the devices' rows. */
class Board {
  constructor(links, devices, linkBody, deviceBody) {
    this.summary = h('p', { class: 'summary', id: 'summary' });
    this.linkBody = linkBody;
    this.deviceBody = deviceBody;
    this.deviceRows = new Map();
    this.linksByName = new Map(links.links.map((l) => [l.name, l]));
    this.devicesByName = new Map(devices.devices.map((d) => [d.name, d]));
  }

  renderSummary() { summaryBadges(this.summary, this.linksByName, this.devicesByName); }

  renderLinks() { linkRows(this.linkBody, this.linksByName); }

  addDevice(d) {
    const { row, update } = deviceRow(d);
    this.deviceRows.set(d.name, { row, update });
    this.deviceBody.append(row);
  }

  /** Fresh lists: links replaced, devices updated, added (declared at run time) or gone. */
  refresh(fresh, counters) {
    this.linksByName.clear();
    for (const l of fresh.links) this.linksByName.set(l.name, l);
    this.renderLinks();
    const listed = new Set();
    for (const d of counters.devices) {
      listed.add(d.name);
      this.devicesByName.set(d.name, d);
      if (this.deviceRows.has(d.name)) this.deviceRows.get(d.name).update(d);
      else this.addDevice(d);
    }
    for (const [name, { row }] of this.deviceRows) {
      if (listed.has(name)) continue;
      row.remove();
      this.deviceRows.delete(name);
      this.devicesByName.delete(name);
    }
    this.renderSummary();
  }

  diagnostics(data) {
    this.devicesByName.set(data.device, { ...this.devicesByName.get(data.device), ...data });
    this.deviceRows.get(data.device)?.update(data);
    this.renderSummary();
  }
}

function statuses(signal) {
  return Promise.all([api('GET', '/links', undefined, { signal }), api('GET', '/devices', undefined, { signal }),
    mqttStatus(signal), configStatus(signal), serialStatus(signal)]);
}

export async function overview(signal) {
  const [links, devices, mqtt, config, serial] = await statuses(signal);
  const status = statusSections();
  const tx = tableSection('tx', 'Standing transactions',
    ['Name', 'Link', 'Kind', 'State', 'Value', 'Runs', 'Failures', 'Last run']);
  tx.section.hidden = true;
  const linksSection = tableSection('links', 'Links', ['Link', 'Endpoint', 'State', 'Utilisation', 'Devices']);
  const devicesSection = tableSection('devices', 'Devices',
    ['Device', 'Profile', 'Link', 'State', 'I/O cycles', 'Last response'], { tableId: 'devices' });
  const board = new Board(links, devices, linksSection.body, devicesSection.body);
  fill(main, h('h1', {}, 'Overview'), board.summary, linksSection.section, devicesSection.section,
    status.servers, status.serial, status.mqtt, tx.section, status.config);
  status.render(serial, mqtt, config);
  board.renderLinks();
  for (const d of devices.devices) board.addDevice(d);
  board.renderSummary();

  // State changes arrive as events at once; counters (cycles, response time, utilisation)
  // are refreshed every two seconds.
  const poll = setInterval(async () => {
    try {
      const [fresh, counters, m, c, s] = await statuses(signal);
      status.render(s, m, c);
      board.refresh(fresh, counters);
    } catch { /* the event stream reports a lost gateway */ }
  }, REFRESH_MS);
  signal.addEventListener('abort', () => clearInterval(poll), { once: true });

  const transactions = new Map();
  follow('/events?values=false', (name, data) => {
    if (name === 'diagnostics') {
      board.diagnostics(data);
    } else if (name === 'transaction') {
      transactions.set(data.name, data);
      tx.section.hidden = transactions.size === 0;
      transactionRows(tx.body, transactions);
    }
  }, signal);
}
