// The gateway's REST API and event stream, with the visitor's token when one is needed.

const TOKEN_KEY = 'iogate-token';

export function token() {
  try { return sessionStorage.getItem(TOKEN_KEY) || ''; } catch { return ''; }
}

export function setToken(value) {
  try {
    if (value) sessionStorage.setItem(TOKEN_KEY, value); else sessionStorage.removeItem(TOKEN_KEY);
  } catch { /* storage refused: the token lasts as long as this page */ }
  memoryToken = value;
}

let memoryToken = token();

function headers(extra) {
  const h = { Accept: 'application/json', ...extra };
  if (memoryToken) h.Authorization = `Bearer ${memoryToken}`;
  return h;
}

/** An error answered by the API, in its own words. */
export class ApiError extends Error {
  constructor(status, code, message) {
    super(message);
    this.status = status;
    this.code = code;
  }
}

/** One request to `/api/v1{path}`; the parsed JSON (or text), or an ApiError. */
export async function api(method, path, body, { signal, text = false } = {}) {
  let response;
  try {
    response = await fetch(`/api/v1${path}`, {
      method,
      headers: headers(body === undefined ? {} : { 'Content-Type': 'application/json' }),
      body: body === undefined ? undefined : JSON.stringify(body),
      cache: 'no-store',
      signal,
    });
  } catch (e) {
    if (e.name === 'AbortError') throw e;
    throw new ApiError(0, 'unreachable', 'the gateway cannot be reached');
  }
  const raw = await response.text();
  if (!response.ok) {
    let code = `http_${response.status}`;
    let message = raw || response.statusText;
    try {
      const parsed = JSON.parse(raw);
      if (parsed && parsed.error) ({ code, message } = parsed.error);
    } catch { /* not JSON: keep the text */ }
    throw new ApiError(response.status, code, message);
  }
  if (text) return raw;
  return raw ? JSON.parse(raw) : null;
}

/**
 * Reads the Server-Sent Events of `/api/v1{path}` (with the token, which EventSource
 * cannot send), calling `onEvent(name, data)` for each; `onOpen()` once connected.
 * Resolves when the stream ends; rejects with an ApiError or a network error.
 */
export async function events(path, { onOpen, onEvent, signal }) {
  let response;
  try {
    response = await fetch(`/api/v1${path}`, {
      headers: headers({ Accept: 'text/event-stream' }),
      cache: 'no-store',
      signal,
    });
  } catch (e) {
    if (e.name === 'AbortError') throw e;
    throw new ApiError(0, 'unreachable', 'the gateway cannot be reached');
  }
  if (!response.ok) {
    let code = `http_${response.status}`;
    let message = response.statusText;
    try { ({ code, message } = (await response.json()).error); } catch { /* keep */ }
    throw new ApiError(response.status, code, message);
  }
  onOpen?.();
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = '';
  let name = 'message';
  let data = [];
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let end;
    while ((end = buffer.indexOf('\n')) >= 0) {
      const line = buffer.slice(0, end).replace(/\r$/, '');
      buffer = buffer.slice(end + 1);
      if (line === '') {
        if (data.length) {
          let parsed = null;
          try { parsed = JSON.parse(data.join('\n')); } catch { parsed = null; }
          if (parsed !== null) onEvent(name, parsed);
        }
        name = 'message';
        data = [];
      } else if (line.startsWith('event:')) {
        name = line.slice(6).trim();
      } else if (line.startsWith('data:')) {
        data.push(line.slice(5).replace(/^ /, ''));
      }
    }
  }
}
