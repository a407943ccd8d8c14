// A link's page: its state and endpoint, its devices, its poll plan with wire times, and a
// scan for the devices on its line.

import { api } from './api.js';
import { h, fill, text } from './dom.js';
import { main, follow } from './connection.js';
import { LINK_CODES, REFRESH_MS, enc, percent, linkState, endpointOf } from './view.js';

/** What a driver tells of the device at the other end, by its key. */
const PEER = {
  order_number: 'Order number', module: 'Module', serial_number: 'Serial number',
  pdu_size: 'PDU size', cpu_state: 'CPU state',
};

export async function linkView(name, signal) {
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
      h('dt', {}, 'Utilisation'), h('dd', {}, `${percent(l.utilisation)} measured, ${percent(l.planned_utilisation)} planned`),
      ...Object.entries(l.peer ?? {}).flatMap(([k, v]) => [h('dt', {}, PEER[k] ?? k), h('dd', { 'data-peer': k }, v)]));
    fill(devices, ...l.devices.map((d) => h('li', {}, h('a', { href: `#/devices/${enc(d)}` }, d))));
    return l;
  }
  const first = await refresh();
  // A scan probes Modbus slave ids: links of other protocols have none.
  const modbus = first.kind === 'serial' || first.kind === 'tcp';
  text(plan, await api('GET', `/links/${enc(name)}/plan`, undefined, { signal, text: true }));
  fill(main,
    h('p', { class: 'crumbs' }, h('a', { href: '#/' }, 'Overview'), ' › ', name),
    h('h1', {}, name, ' ', state),
    facts,
    h('h2', {}, 'Devices'), devices,
    h('h2', {}, 'Poll plan'),
    h('p', { class: 'meaning' }, 'How each device is read (on a Modbus line, its transactions with their wire time), as `iogate plan` prints it.'),
    plan,
    ...(modbus ? [scanSection(name, signal)] : []));
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
