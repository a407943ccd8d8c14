// The iogate web page: an overview of links and devices, and a page per device with its
// fields live from the event stream, inputs of simulated devices set and outputs written,
// and a page per link. Here the router; each view in its module.

import { ApiError } from './api.js';
import { main, askToken, lost, onRerender, showError, sleep } from './connection.js';
import { deviceView } from './device.js';
import { linkView } from './link.js';
import { overview } from './overview.js';

let current = null; // { abort: AbortController }

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
onRerender(render);
render();
