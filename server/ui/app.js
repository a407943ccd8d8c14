// The iogate web page: an overview of links and devices, and a page per device with its
// fields live from the event stream, inputs of simulated devices set and outputs written.

import { api, events, ApiError, setToken } from './api.js';
import { h, fill, text, sparkline } from './dom.js';
import { ago, cell, plural, mqttStatus, mqttRows, serialStatus, serialRows, configStatus, configRows, serverRows } from './sections.js';

// Source document 000's error codes, in its words.
const LINK_CODES = {
  0: 'OK — port is open',
  1: 'No port configured (port string is empty)',
  2: 'Port open failed (device doesn’t exist, permission denied, or busy)',
  3: 'Port lost (was open, now disconnected)',
};
const DEVICE_CODES = {
  0: 'OK — device is responding',
  1: 'No link configured (link string is empty)',
  2: 'No slave configured (slave_id is 0)',
  10: 'Communication error (timeout, CRC mismatch, or device not responding)',
};
// Seed 002's transaction states.
const TRANSACTION_STATES = {
  0: 'not run yet',
  4: 'done',
  [-1]: 'interface unavailable',
  [-2]: 'response timeout',
  [-3]: 'unknown error',
};
const NUMERIC = new Set(['SINT', 'INT', 'DINT', 'LINT', 'USINT', 'UINT', 'UDINT', 'ULINT',
  'BYTE', 'WORD', 'DWORD', 'LWORD', 'REAL', 'LREAL']);
const TREND_POINTS = 60;
const REFRESH_MS = 2000;

const main = document.getElementById('main');
const banner = document.getElementById('banner');
const connection = document.getElementById('connection');

let current = null; // { abort: AbortController }

// ---------------------------------------------------------------- connection state

function connected() {
  connection.className = 'connection live';
  text(connection, 'live');
  banner.hidden = true;
}

function lost(reason) {
  connection.className = 'connection lost';
  text(connection, 'connection lost');
  fill(banner, h('strong', {}, 'Connection to the gateway lost'),
    ` (${reason}). Values shown are the last received; reconnecting…`);
  banner.hidden = false;
}

function sleep(ms, signal) {
  return new Promise((resolve) => {
    const timer = setTimeout(resolve, ms);
    signal.addEventListener('abort', () => { clearTimeout(timer); resolve(); }, { once: true });
  });
}

/** Asks for a token (the API answered 401), then shows the page again. */
function askToken(message) {
  const dialog = document.getElementById('login');
  const form = document.getElementById('login-form');
  const input = document.getElementById('login-token');
  text(document.getElementById('login-reason'), message);
  if (dialog.open) return;
  form.onsubmit = (event) => {
    event.preventDefault();
    setToken(input.value.trim());
    input.value = '';
    dialog.close();
    render();
  };
  dialog.showModal();
  input.focus();
}

/**
 * Follows the event stream at `path` for as long as the view lives, reconnecting with
 * backoff; after a lost connection the view is built again from fresh data.
 */
async function follow(path, onEvent, signal) {
  let delay = 500;
  let wasLost = false;
  while (!signal.aborted) {
    try {
      await events(path, {
        signal,
        onEvent,
        onOpen: () => {
          connected();
          delay = 500;
          if (wasLost) render();
        },
      });
      if (signal.aborted) return;
      wasLost = true;
      lost('the gateway closed the event stream');
    } catch (e) {
      if (signal.aborted || e.name === 'AbortError') return;
      if (e instanceof ApiError && e.status === 401) { askToken(e.message); return; }
      if (e instanceof ApiError && e.status >= 400 && e.status < 500) {
        showError(e);
        return;
      }
      wasLost = true;
      lost(e.message);
    }
    await sleep(delay, signal);
    delay = Math.min(delay * 2, 5000);
  }
}

function showError(e) {
  fill(main, h('h1', {}, 'Cannot show this'),
    h('p', { class: 'error', role: 'alert' }, e.message),
    h('p', {}, h('a', { href: '#/' }, 'Back to the overview')));
}

// ---------------------------------------------------------------- formatting

function formatValue(type, value) {
  if (value === null || value === undefined) return '—';
  if (type === 'BOOL') return value ? 'TRUE' : 'FALSE';
  if (type === 'REAL' || type === 'LREAL') {
    return Number.isInteger(value) ? String(value) : String(Number(value.toPrecision(7)));
  }
  if (type === 'TIME') return `${value} ms`;
  return String(value);
}

function percent(ratio) {
  return ratio === undefined || ratio === null ? '—' : `${(ratio * 100).toFixed(1)} %`;
}

/** A typed value from what was typed: the API checks it and names what is wrong. */
function parseInput(type, raw) {
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

const enc = encodeURIComponent;

/** A link or device that is connected with error code 0. */
function healthy(x) {
  return x.connected && x.error_code === 0;
}

/** A table head with these column names. */
function head(...names) {
  return h('thead', {}, h('tr', {}, ...names.map((c) => h('th', { scope: 'col' }, c))));
}

/** Calls `load` the first time `details` is opened. */
function loadOnOpen(details, load) {
  details.addEventListener('toggle', () => {
    if (!details.open || details.dataset.loaded) return;
    details.dataset.loaded = '1';
    load();
  });
  return details;
}

// ---------------------------------------------------------------- overview

function linkState(link) {
  const ok = healthy(link);
  return h('span', { class: `badge ${ok ? 'ok' : 'bad'}` },
    ok ? 'connected' : `error ${link.error_code}`);
}

function deviceState(d) {
  const ok = healthy(d);
  return h('span', { class: `badge ${ok ? 'ok' : 'bad'}`, 'data-state': ok ? 'connected' : 'disconnected' },
    ok ? 'connected' : `disconnected · error ${d.error_code}`);
}

async function overview(signal) {
  const [links, devices, mqtt, config, serial] = await Promise.all([api('GET', '/links', undefined, { signal }),
    api('GET', '/devices', undefined, { signal }), mqttStatus(signal), configStatus(signal), serialStatus(signal)]);
  const serialBody = h('tbody');
  const serialSection = h('section', { hidden: !serial, 'aria-labelledby': 'serial-title', id: 'serial' },
    h('h2', { id: 'serial-title' }, 'Modbus server on serial lines'),
    h('div', { class: 'scroll' }, h('table', { class: 'list' },
      head('Port', 'Unit id', 'State', 'Frames'), serialBody)));
  const renderSerial = (ports) => {
    serialSection.hidden = !ports;
    if (ports) fill(serialBody, ...serialRows(ports));
  };
  const configBody = h('tbody');
  const configSection = h('section', { 'aria-labelledby': 'config-title', id: 'config', hidden: !config },
    h('h2', { id: 'config-title' }, 'Configuration'),
    h('div', { class: 'scroll' }, h('table', { class: 'list' }, configBody)));
  const serverBody = h('tbody');
  const serverSection = h('section', { 'aria-labelledby': 'servers-title', id: 'servers', hidden: true },
    h('h2', { id: 'servers-title' }, 'Servers'),
    h('div', { class: 'scroll' }, h('table', { class: 'list' }, serverBody)));
  const renderConfig = (c) => {
    configSection.hidden = !c;
    if (c) fill(configBody, ...configRows(c));
    serverSection.hidden = !c?.listening?.length;
    if (c?.listening) fill(serverBody, ...serverRows(c.listening));
  };
  const mqttBody = h('tbody');
  const mqttSection = h('section', { hidden: !mqtt, 'aria-labelledby': 'mqtt-title', id: 'mqtt' },
    h('h2', { id: 'mqtt-title' }, 'MQTT'),
    h('div', { class: 'scroll' }, h('table', { class: 'list' }, mqttBody)));
  const renderMqtt = (m) => {
    mqttSection.hidden = !m;
    if (m) fill(mqttBody, ...mqttRows(m));
  };
  const summary = h('p', { class: 'summary', id: 'summary' });
  const linkBody = h('tbody');
  const deviceBody = h('tbody');
  const transactionBody = h('tbody');
  const transactionSection = h('section', { hidden: true, 'aria-labelledby': 'tx-title' },
    h('h2', { id: 'tx-title' }, 'Standing transactions'),
    h('div', { class: 'scroll' }, h('table', { class: 'list' },
      head('Name', 'Link', 'Kind', 'State', 'Value', 'Runs', 'Failures', 'Last run'),
      transactionBody)));
  const deviceRows = new Map();
  const linksByName = new Map(links.links.map((l) => [l.name, l]));
  const devicesByName = new Map(devices.devices.map((d) => [d.name, d]));

  function renderSummary() {
    const linksDown = [...linksByName.values()].filter((l) => !healthy(l)).length;
    const devicesDown = [...devicesByName.values()].filter((d) => !healthy(d)).length;
    fill(summary,
      h('span', { class: `badge ${linksDown ? 'bad' : 'ok'}` },
        `${linksByName.size} link${linksByName.size === 1 ? '' : 's'}${linksDown ? `, ${linksDown} down` : ''}`),
      ' ',
      h('span', { class: `badge ${devicesDown ? 'bad' : 'ok'}` },
        `${devicesByName.size} device${devicesByName.size === 1 ? '' : 's'}${devicesDown ? `, ${devicesDown} not answering` : ''}`));
  }

  function renderLinks() {
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
    deviceRows.set(d.name, { row, update });
    return row;
  }

  fill(main,
    h('h1', {}, 'Overview'),
    summary,
    h('section', { 'aria-labelledby': 'links-title' },
      h('h2', { id: 'links-title' }, 'Links'),
      h('div', { class: 'scroll' }, h('table', { class: 'list' },
        head('Link', 'Endpoint', 'State', 'Utilisation', 'Devices'),
        linkBody))),
    h('section', { 'aria-labelledby': 'devices-title' },
      h('h2', { id: 'devices-title' }, 'Devices'),
      h('div', { class: 'scroll' }, h('table', { class: 'list', id: 'devices' },
        head('Device', 'Profile', 'Link', 'State', 'I/O cycles', 'Last response'),
        deviceBody))),
    serverSection,
    serialSection,
    mqttSection,
    transactionSection,
    configSection);
  renderSerial(serial);
  renderMqtt(mqtt);
  renderConfig(config);
  renderLinks();
  fill(deviceBody, ...devices.devices.map(deviceRow));
  renderSummary();

  const transactions = new Map();
  function renderTransactions() {
    transactionSection.hidden = transactions.size === 0;
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

  // State changes arrive as events at once; counters (cycles, response time, utilisation)
  // are refreshed every two seconds.
  const poll = setInterval(async () => {
    try {
      const [fresh, counters, m, c, s] = await Promise.all([api('GET', '/links', undefined, { signal }),
        api('GET', '/devices', undefined, { signal }), mqttStatus(signal), configStatus(signal), serialStatus(signal)]);
      renderSerial(s);
      renderMqtt(m);
      renderConfig(c);
      linksByName.clear();
      for (const l of fresh.links) linksByName.set(l.name, l);
      renderLinks();
      // Devices declared or removed at run time come and go here.
      const listed = new Set();
      for (const d of counters.devices) {
        listed.add(d.name);
        devicesByName.set(d.name, d);
        if (deviceRows.has(d.name)) deviceRows.get(d.name).update(d);
        else deviceBody.append(deviceRow(d));
      }
      for (const [name, { row }] of deviceRows) {
        if (listed.has(name)) continue;
        row.remove();
        deviceRows.delete(name);
        devicesByName.delete(name);
      }
      renderSummary();
    } catch { /* the event stream reports a lost gateway */ }
  }, REFRESH_MS);
  signal.addEventListener('abort', () => clearInterval(poll), { once: true });

  follow('/events?values=false', (name, data) => {
    if (name === 'diagnostics') {
      devicesByName.set(data.device, { ...devicesByName.get(data.device), ...data });
      deviceRows.get(data.device)?.update(data);
      renderSummary();
    } else if (name === 'transaction') {
      transactions.set(data.name, data);
      renderTransactions();
    }
  }, signal);
}

// ---------------------------------------------------------------- a device

/** Follows the outcome of write `generation` until it is no longer pending. */
async function followWrite(generation, out, signal) {
  const started = Date.now();
  while (!signal.aborted && Date.now() - started < 60000) {
    let w;
    try {
      w = await api('GET', `/writes/${generation}`, undefined, { signal });
    } catch (e) {
      if (e.name === 'AbortError') return;
      out.className = 'outcome error';
      text(out, e.message);
      return;
    }
    out.dataset.status = w.status;
    if (w.status !== 'pending') {
      out.className = `outcome ${w.status === 'failed' ? 'error' : w.status}`;
      text(out, w.status === 'failed' ? `failed: ${w.error ?? 'no reason given'}`
        : `${w.status}${w.attempts > 1 ? ` after ${w.attempts} attempts` : ''}`);
      return;
    }
    text(out, 'pending…');
    await sleep(200, signal);
  }
}

function fieldControl(device, f, simulated, signal, currentValue) {
  // Outputs (and in-outs) are written as clients write them; a simulated device's inputs
  // are set as the device itself would change them.
  const isOutput = f.direction === 'output' || f.direction === 'inout';
  if (!isOutput && !simulated) return null;
  const path = `/devices/${enc(device)}/fields/${enc(f.field)}${isOutput ? '' : '/simulate'}`;
  const verb = isOutput ? 'Write' : 'Set';
  const out = h('output', { class: 'outcome', 'aria-live': 'polite' });

  async function send(value) {
    out.className = 'outcome';
    delete out.dataset.status;
    text(out, 'sending…');
    try {
      const answer = await api('PUT', path, { value }, { signal });
      if (isOutput && answer && answer.generation !== undefined) {
        text(out, 'pending…');
        out.dataset.status = 'pending';
        await followWrite(answer.generation, out, signal);
      } else {
        out.className = 'outcome written';
        out.dataset.status = 'set';
        text(out, 'set');
      }
    } catch (e) {
      if (e.name === 'AbortError') return;
      if (e instanceof ApiError && e.status === 401) askToken(e.message);
      out.className = 'outcome error';
      out.dataset.status = 'error';
      text(out, e.message);
    }
  }

  if (f.type === 'BOOL') {
    const button = h('button', {
      type: 'button', class: 'toggle', 'aria-label': `Toggle ${f.field}`,
      onclick: () => send(!currentValue()),
    }, isOutput ? 'Toggle' : 'Toggle input');
    return h('div', { class: 'control' }, button, out);
  }
  const input = h('input', {
    type: 'text', inputmode: NUMERIC.has(f.type) ? 'decimal' : 'text',
    'aria-label': `New value of ${f.field}`, placeholder: f.type === 'TIME' ? 'ms or T#1s500ms' : f.type,
    autocomplete: 'off', spellcheck: 'false',
  });
  const form = h('form', {
    class: 'control',
    onsubmit: (event) => { event.preventDefault(); send(parseInput(f.type, input.value)); },
  }, input, h('button', { type: 'submit', 'aria-label': `${verb} ${f.field}` }, verb), out);
  return form;
}

async function deviceView(name, signal) {
  const detail = await api('GET', `/devices/${enc(name)}`, undefined, { signal });
  const simulated = detail.protocol === 'simulated';
  let profile = null;
  try { profile = await api('GET', `/profiles/${enc(detail.profile)}`, undefined, { signal }); } catch { /* shown without */ }
  const meta = new Map((profile?.fields ?? []).map((f) => [f.name, f]));

  const state = h('span', {});
  const cycles = h('span', {});
  const response = h('span', {});
  const meaning = h('span', {});
  function diagnostics(d) {
    fill(state, deviceState(d));
    text(meaning, `${d.error_code} — ${DEVICE_CODES[d.error_code] ?? 'unknown code'}`);
    text(cycles, d.io_cycles);
    text(response, `${Number(d.last_response_ms).toFixed(1)} ms`);
  }
  diagnostics(detail);

  const rows = new Map();
  const body = h('tbody');
  for (const [fieldName, f] of Object.entries(detail.fields)) {
    const m = meta.get(fieldName);
    let last = f;
    const trend = [];
    const valueCell = h('td', { 'data-label': 'Value', class: 'value' });
    const quality = h('td', { 'data-label': 'Quality' });
    // Events come when a value or its quality changes: the age shown is since the last
    // change (a value read again unchanged keeps it; its quality says whether it is fresh).
    const ageCell = h('td', { 'data-label': 'Changed', class: 'age' });
    const trendCell = h('td', { 'data-label': 'Trend', class: 'trend' });
    const control = fieldControl(name, f, simulated, signal, () => last.value);
    const row = h('tr', { 'data-field': fieldName },
      h('th', { scope: 'row' }, fieldName,
        m?.description ? h('div', { class: 'meaning' }, m.description) : null),
      valueCell,
      h('td', { 'data-label': 'Unit' }, f.unit ?? ''),
      h('td', { 'data-label': 'Type' }, f.type),
      h('td', { 'data-label': 'Direction' }, f.direction),
      quality, ageCell, trendCell,
      h('td', { 'data-label': control ? (f.direction === 'input' ? 'Simulate' : 'Write') : '' }, control));
    function update(v) {
      last = v;
      const good = v.quality === 'good';
      // A value that is not good is the last good one (or none): shown, but dimmed.
      valueCell.classList.toggle('dim', !good);
      fill(valueCell, h('span', { class: 'v', title: good ? null : 'the last good value' },
        formatValue(v.type, v.value)),
        v.mismatch ? h('div', { class: 'meaning warn' },
          `device holds this; requested ${formatValue(v.type, v.desired)}`) : null);
      fill(quality, h('span', { class: `badge q-${v.quality} ${good ? 'ok' : 'bad'}` }, v.quality.replace('_', ' ')),
        v.error ? h('div', { class: 'meaning' }, v.error) : null);
      ageCell.dataset.timestamp = v.timestamp ?? '';
      text(ageCell, ago(v.timestamp));
      if (NUMERIC.has(v.type) && typeof v.value === 'number' && good) {
        trend.push(v.value);
        if (trend.length > TREND_POINTS) trend.shift();
        fill(trendCell, sparkline(trend, `recent values of ${fieldName}`));
      }
    }
    update(f);
    rows.set(fieldName, update);
    body.append(row);
  }

  const st = h('pre', { class: 'code' }, '…');
  const layout = h('tbody');
  for (const e of profile?.layout ?? []) {
    layout.append(h('tr', {}, cell('Member', e.name), cell('Type', e.type),
      cell('Section', e.section), cell('Role', e.role), cell('Description', e.description)));
  }
  const stDetails = loadOnOpen(h('details', {}, h('summary', {}, 'ST declaration'), st), async () => {
    try {
      text(st, await api('GET', `/profiles/${enc(detail.profile)}/st`, undefined, { signal, text: true }));
    } catch (e) { text(st, e.message); }
  });
  const mapBody = h('tbody');
  const mapNote = h('p', { class: 'meaning' });
  const mapSection = loadOnOpen(h('details', {}, h('summary', {}, 'Modbus TCP server addresses'), mapNote,
    h('div', { class: 'scroll' }, h('table', { class: 'list' },
      head('Located address', 'Table', 'Address', 'Field', 'Type', 'Access'), mapBody))), async () => {
    try {
      const map = await api('GET', '/map', undefined, { signal });
      const mine = map.bindings.filter((b) => b.device === name);
      text(mapNote, mine.length ? `unit id ${map.unit_id}, ${map.address_space} address space`
        : 'No field of this device is bound to a located address.');
      fill(mapBody, ...mine.map((b) => h('tr', {}, cell('Located address', b.at), cell('Table', b.table),
        cell('Address', String(b.address)), cell('Field', b.field), cell('Type', b.type), cell('Access', b.access))));
    } catch (e) {
      text(mapNote, e.message);
    }
  });

  fill(main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Overview'), ' › ', name),
    h('h1', {}, name, ' ', state),
    h('dl', { class: 'facts' },
      h('dt', {}, 'Profile'), h('dd', {}, detail.profile, profile?.vendor ? ` (${profile.vendor})` : ''),
      h('dt', {}, 'Link'), h('dd', {}, simulated || !detail.link ? 'simulated'
        : [h('a', { href: `#/links/${enc(detail.link)}` }, detail.link), detail.slave_id ? ` · slave ${detail.slave_id}` : '']),
      h('dt', {}, 'Refresh rate'), h('dd', {}, `${detail.refresh_rate_ms} ms`),
      h('dt', {}, 'Error code'), h('dd', {}, meaning),
      h('dt', {}, 'I/O cycles'), h('dd', {}, cycles),
      h('dt', {}, 'Last response'), h('dd', {}, response)),
    simulated ? h('p', { class: 'hint' }, 'A simulated device: set its inputs here and watch its outputs change as clients write them.') : null,
    h('section', { 'aria-labelledby': 'fields-title' },
      h('h2', { id: 'fields-title' }, 'Fields'),
      h('div', { class: 'scroll' }, h('table', { class: 'fields list', id: 'fields' },
        head('Field', 'Value', 'Unit', 'Type', 'Direction', 'Quality', 'Changed', 'Trend', ''),
        body))),
    h('section', { 'aria-labelledby': 'profile-title' },
      h('h2', { id: 'profile-title' }, 'Profile'),
      h('details', {}, h('summary', {}, 'Function-block layout'),
        h('div', { class: 'scroll' }, h('table', { class: 'list' },
          head('Member', 'Type', 'Section', 'Role', 'Description'), layout))),
      stDetails,
      mapSection));

  const ages = setInterval(() => {
    for (const td of body.querySelectorAll('td.age')) text(td, ago(td.dataset.timestamp));
  }, 1000);
  // The device's counters (cycles, response time); its values and state come as events.
  const counters = setInterval(async () => {
    try {
      const list = await api('GET', '/devices', undefined, { signal });
      const d = list.devices.find((x) => x.name === name);
      if (d) diagnostics(d);
    } catch { /* the event stream reports a lost gateway */ }
  }, REFRESH_MS);
  signal.addEventListener('abort', () => {
    clearInterval(ages);
    clearInterval(counters);
  }, { once: true });

  follow(`/events?device=${enc(name)}`, (event, data) => {
    if (event === 'value') rows.get(data.field)?.(data);
    else if (event === 'diagnostics') diagnostics(data);
  }, signal);
}

// ---------------------------------------------------------------- a link

function endpointOf(l) {
  return l.kind === 'serial'
    ? `${l.port} · ${l.baud} ${l.data_bits}${l.parity}${l.stop_bits}${l.framing === 'ascii' ? ' · ASCII' : ''}`
    : `${l.host}:${l.tcp_port} (${l.framing})`;
}

async function linkView(name, signal) {
  const facts = h('dl', { class: 'facts' });
  const state = h('span', {});
  const plan = h('pre', { class: 'code', id: 'plan' }, '…');
  const devices = h('ul', { class: 'devices' });
  async function refresh() {
    const l = await api('GET', `/links/${enc(name)}`, undefined, { signal });
    fill(state, linkState(l));
    fill(facts,
      h('dt', {}, 'Endpoint'), h('dd', {}, endpointOf(l)),
      h('dt', {}, 'Error code'), h('dd', {}, `${l.error_code} — ${LINK_CODES[l.error_code] ?? ''}`),
      h('dt', {}, 'Utilisation'), h('dd', {}, `${percent(l.utilisation)} measured, ${percent(l.planned_utilisation)} planned`));
    fill(devices, ...l.devices.map((d) => h('li', {}, h('a', { href: `#/devices/${enc(d)}` }, d))));
  }
  await refresh();
  text(plan, await api('GET', `/links/${enc(name)}/plan`, undefined, { signal, text: true }));
  fill(main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Overview'), ' › ', name),
    h('h1', {}, name, ' ', state),
    facts,
    h('h2', {}, 'Devices'), devices,
    h('h2', {}, 'Poll plan'),
    h('p', { class: 'meaning' }, 'Each device\'s read transactions with their wire time, as `iogate plan` prints them.'),
    plan,
    scanSection(name, signal));
  const poll = setInterval(() => refresh().catch(() => { /* shown by the overview's stream */ }), REFRESH_MS);
  signal.addEventListener('abort', () => clearInterval(poll), { once: true });
  follow('/events?values=false', (event) => {
    if (event === 'diagnostics') refresh().catch(() => {});
  }, signal);
}

/** One device a scan found, as a list item. */
function foundItem(d) {
  const id = d.identification;
  const who = id ? [id.vendor, id.product_code, id.revision].filter(Boolean).join(' · ') : 'no identification (FC 43)';
  const reads = d.reads.map((r) => `FC${String(r.function).padStart(2, '0')} ${r.address}: ${r.exception ? `exception ${r.exception}` : r.answer}`);
  return h('li', { 'data-slave': String(d.slave_id) },
    h('strong', {}, `slave ${d.slave_id}`), ` at ${d.setting.baud} 8${d.setting.parity}1 — ${who}`,
    d.collision ? h('div', { class: 'error' }, `Collision: ${d.collision}`) : '',
    d.garbled ? h('div', { class: 'error' }, `Unreadable answers: ${d.garbled}`) : '',
    h('div', { class: 'meaning' }, reads.join('; ')),
    h('div', {}, d.profiles.length
      ? `Profiles: ${d.profiles.map((p) => p.identified ? `${p.profile} (identified)` : p.telling ? p.profile : `${p.profile} (registers only)`).join(', ')}`
      : 'No profile fits.'));
}

/** The link's scan: ids and slot, a button, progress, devices found and their entries. */
function scanSection(name, signal) {
  const ids = h('input', { id: 'scan-ids', value: '1-247', size: '12', 'aria-label': 'Slave ids' });
  const slot = h('input', { id: 'scan-timeout', value: '50ms', size: '6', 'aria-label': 'Slot per probe' });
  const button = h('button', { id: 'scan-start', type: 'button' }, 'Scan');
  const status = h('p', { id: 'scan-status', role: 'status' });
  const bar = h('progress', { id: 'scan-progress', max: '1', value: '0' });
  const found = h('ul', { id: 'scan-found', class: 'devices' });
  const config = h('pre', { id: 'scan-config', class: 'code' });
  function show(s) {
    bar.max = String(s.total);
    bar.value = String(s.probed);
    const took = `${(s.elapsed_ms / 1000).toFixed(1)} s`;
    text(status, s.state === 'running'
      ? `Scanning ids ${s.ids} (at most ${(s.estimate_ms / 1000).toFixed(1)} s between polls): ${s.probed} of ${s.total}, ${s.devices.length} found`
      : s.state === 'done' ? `Done in ${took}: ${s.devices.length} device${s.devices.length === 1 ? '' : 's'} found`
        : `Scan ${s.state}${s.error ? `: ${s.error}` : ''}`);
    fill(found, ...s.devices.map(foundItem));
    text(config, s.config);
  }
  button.addEventListener('click', async () => {
    button.disabled = true;
    try {
      let s = await api('POST', `/links/${enc(name)}/scan`, { ids: ids.value, timeout: slot.value }, { signal });
      show(s);
      while (s.state === 'running' && !signal.aborted) {
        await new Promise((resolve) => setTimeout(resolve, 500));
        s = await api('GET', `/scans/${s.id}`, undefined, { signal });
        show(s);
      }
    } catch (e) {
      if (!signal.aborted) text(status, e.message);
    } finally {
      button.disabled = false;
    }
  });
  return h('section', { 'aria-labelledby': 'scan-title' },
    h('h2', { id: 'scan-title' }, 'Scan for devices'),
    h('p', { class: 'meaning' }, 'Probes each slave id between polls, one probe at a time (role admin).'),
    h('p', {}, 'Ids ', ids, ' slot ', slot, ' ', button),
    status, bar, found, config);
}

// ---------------------------------------------------------------- routing

async function render() {
  current?.abort.abort();
  const abort = new AbortController();
  current = { abort };
  const route = location.hash.replace(/^#/, '') || '/';
  const device = route.match(/^\/devices\/(.+)$/);
  const link = route.match(/^\/links\/(.+)$/);
  try {
    if (link) {
      document.title = `${decodeURIComponent(link[1])} · iogate`;
      await linkView(decodeURIComponent(link[1]), abort.signal);
    } else if (device) {
      document.title = `${decodeURIComponent(device[1])} · iogate`;
      await deviceView(decodeURIComponent(device[1]), abort.signal);
    } else {
      document.title = 'iogate';
      await overview(abort.signal);
    }
  } catch (e) {
    if (abort.signal.aborted || e.name === 'AbortError') return;
    if (e instanceof ApiError && e.status === 401) { askToken(e.message); return; }
    if (e instanceof ApiError && e.status === 0) {
      lost(e.message);
      await sleep(2000, abort.signal);
      if (!abort.signal.aborted) render();
      return;
    }
    showError(e);
  }
}

window.addEventListener('hashchange', () => {
  render();
  main.focus({ preventScroll: true });
});
render();
