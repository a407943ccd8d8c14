// The page's connection to the gateway: its state shown, a token asked for when the API
// wants one, event streams followed with reconnects, and an error shown in place of a view.

import { events, ApiError, setToken } from './api.js';
import { h, fill, text } from './dom.js';

/** Shows the page again (the router's `render`, set by app.js). */
let rerender = () => {};

export function onRerender(render) {
  rerender = render;
}

export const main = document.getElementById('main');
const banner = document.getElementById('banner');
const connection = document.getElementById('connection');


export function connected() {
  connection.className = 'connection live';
  text(connection, 'live');
  banner.hidden = true;
}

export function lost(reason) {
  connection.className = 'connection lost';
  text(connection, 'connection lost');
  fill(banner, h('strong', {}, 'Connection to the gateway lost'),
    ` (${reason}). Values shown are the last received; reconnecting…`);
  banner.hidden = false;
}

export function sleep(ms, signal) {
  return new Promise((resolve) => {
    const timer = setTimeout(resolve, ms);
    signal.addEventListener('abort', () => { clearTimeout(timer); resolve(); }, { once: true });
  });
}

/** Asks for a token (the API answered 401), then shows the page again. */
export function askToken(message) {
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
    rerender();
  };
  dialog.showModal();
  input.focus();
}

/**
 * Follows the event stream at `path` for as long as the view lives, reconnecting with
 * backoff; after a lost connection the view is built again from fresh data.
 */
export async function follow(path, onEvent, signal) {
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
          if (wasLost) rerender();
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

export function showError(e) {
  fill(main, h('h1', {}, 'Cannot show this'),
    h('p', { class: 'error', role: 'alert' }, e.message),
    h('p', {}, h('a', { href: '#/' }, 'Back to the overview')));
}
