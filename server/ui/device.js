// A device's page: its diagnostics, its fields live from the event stream (a simulated
// device's inputs set, outputs written and their outcome followed), its profile's layout
// and ST declaration, and where the Modbus server serves its fields.

import { api, ApiError } from './api.js';
import { h, fill, text, sparkline } from './dom.js';
import { ago, cell } from './sections.js';
import { main, askToken, follow, sleep } from './connection.js';
import {
  DEVICE_CODES, NUMERIC, TREND_POINTS, REFRESH_MS, enc, formatValue, parseInput, head,
  loadOnOpen, deviceState,
} from './view.js';

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

/** A field's row: its value (dimmed when not good), quality, age, trend and control; and
 * what updates it with a fresh value. */
function fieldRow(device, fieldName, f, m, simulated, signal) {
  let last = f;
  const trend = [];
  const valueCell = h('td', { 'data-label': 'Value', class: 'value' });
  const quality = h('td', { 'data-label': 'Quality' });
  // Events come when a value or its quality changes: the age shown is since the last
  // change (a value read again unchanged keeps it; its quality says whether it is fresh).
  const ageCell = h('td', { 'data-label': 'Changed', class: 'age' });
  const trendCell = h('td', { 'data-label': 'Trend', class: 'trend' });
  const control = fieldControl(device, f, simulated, signal, () => last.value);
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
  return { row, update };
}

/** The profile's section: its function-block layout, its ST declaration and the Modbus
 * server's addresses of the device's fields, each loaded when opened. */
function profileSection(name, detail, profile, signal) {
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
  return h('section', { 'aria-labelledby': 'profile-title' },
    h('h2', { id: 'profile-title' }, 'Profile'),
    h('details', {}, h('summary', {}, 'Function-block layout'),
      h('div', { class: 'scroll' }, h('table', { class: 'list' },
        head('Member', 'Type', 'Section', 'Role', 'Description'), layout))),
    stDetails,
    mapSection);
}

/** The device's diagnostics as facts, and what shows fresh ones. */
function diagnosticsFacts(detail, profile, simulated) {
  const state = h('span', {});
  const cycles = h('span', {});
  const response = h('span', {});
  const meaning = h('span', {});
  function show(d) {
    fill(state, deviceState(d));
    text(meaning, `${d.error_code} — ${DEVICE_CODES[d.error_code] ?? 'unknown code'}`);
    text(cycles, d.io_cycles);
    text(response, `${Number(d.last_response_ms).toFixed(1)} ms`);
  }
  show(detail);
  const facts = h('dl', { class: 'facts' },
    h('dt', {}, 'Profile'), h('dd', {}, detail.profile, profile?.vendor ? ` (${profile.vendor})` : ''),
    h('dt', {}, 'Link'), h('dd', {}, simulated || !detail.link ? 'simulated'
      : [h('a', { href: `#/links/${enc(detail.link)}` }, detail.link), detail.slave_id ? ` · slave ${detail.slave_id}` : '']),
    h('dt', {}, 'Refresh rate'), h('dd', {}, `${detail.refresh_rate_ms} ms`),
    h('dt', {}, 'Error code'), h('dd', {}, meaning),
    h('dt', {}, 'I/O cycles'), h('dd', {}, cycles),
    h('dt', {}, 'Last response'), h('dd', {}, response));
  return { state, facts, show };
}

export async function deviceView(name, signal) {
  const detail = await api('GET', `/devices/${enc(name)}`, undefined, { signal });
  const simulated = detail.protocol === 'simulated';
  let profile = null;
  try { profile = await api('GET', `/profiles/${enc(detail.profile)}`, undefined, { signal }); } catch { /* shown without */ }
  const meta = new Map((profile?.fields ?? []).map((f) => [f.name, f]));
  const diagnostics = diagnosticsFacts(detail, profile, simulated);

  const rows = new Map();
  const body = h('tbody');
  for (const [fieldName, f] of Object.entries(detail.fields)) {
    const { row, update } = fieldRow(name, fieldName, f, meta.get(fieldName), simulated, signal);
    rows.set(fieldName, update);
    body.append(row);
  }

  fill(main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Overview'), ' › ', name),
    h('h1', {}, name, ' ', diagnostics.state),
    diagnostics.facts,
    simulated ? h('p', { class: 'hint' }, 'A simulated device: set its inputs here and watch its outputs change as clients write them.') : null,
    h('section', { 'aria-labelledby': 'fields-title' },
      h('h2', { id: 'fields-title' }, 'Fields'),
      h('div', { class: 'scroll' }, h('table', { class: 'fields list', id: 'fields' },
        head('Field', 'Value', 'Unit', 'Type', 'Direction', 'Quality', 'Changed', 'Trend', ''),
        body))),
    profileSection(name, detail, profile, signal));

  const ages = setInterval(() => {
    for (const td of body.querySelectorAll('td.age')) text(td, ago(td.dataset.timestamp));
  }, 1000);
  // The device's counters (cycles, response time); its values and state come as events.
  const counters = setInterval(async () => {
    try {
      const list = await api('GET', '/devices', undefined, { signal });
      const d = list.devices.find((x) => x.name === name);
      if (d) diagnostics.show(d);
    } catch { /* the event stream reports a lost gateway */ }
  }, REFRESH_MS);
  signal.addEventListener('abort', () => {
    clearInterval(ages);
    clearInterval(counters);
  }, { once: true });

  follow(`/events?device=${enc(name)}`, (event, data) => {
    if (event === 'value') rows.get(data.field)?.(data);
    else if (event === 'diagnostics') diagnostics.show(data);
  }, signal);
}
