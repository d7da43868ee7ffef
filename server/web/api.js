// The dashboard's HTTP client: every request carries the team token (when one is set), errors
// become exceptions carrying the API's own message, and server-sent events are read through
// fetch (EventSource cannot send an Authorization header).

export function token() {
  return localStorage.getItem('lightfarm.token') || '';
}

export function setToken(value) {
  localStorage.setItem('lightfarm.token', value);
}

function headers(extra = {}) {
  const h = { ...extra };
  if (token()) h.Authorization = `Bearer ${token()}`;
  return h;
}

export async function request(method, path, body, contentType) {
  const init = { method, headers: headers(contentType ? { 'content-type': contentType } : {}) };
  if (body !== undefined) init.body = body;
  const response = await fetch(path, init);
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    try { message = `${response.status}: ${(await response.json()).error}`; } catch (_) { /* not JSON */ }
    throw new Error(message);
  }
  return response;
}

export async function json(method, path, value) {
  const body = value === undefined ? undefined : JSON.stringify(value);
  return (await request(method, path, body, value === undefined ? undefined : 'application/json')).json();
}

// Calls onEvent(kind, data) for every event of the bake until the stream ends or
// signal aborts.
export async function followEvents(id, onEvent, signal) {
  const response = await fetch(`/v1/bakes/${id}/events`, { headers: headers(), signal });
  if (!response.ok) throw new Error(`${response.status} events`);
  const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = '';
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buffer += value;
    let cut;
    while ((cut = buffer.indexOf('\n\n')) >= 0) {
      const block = buffer.slice(0, cut);
      buffer = buffer.slice(cut + 2);
      let kind = 'message';
      let data = '';
      for (const line of block.split('\n')) {
        if (line.startsWith('event:')) kind = line.slice(6).trim();
        else if (line.startsWith('data:')) data += line.slice(5).trim();
      }
      if (data) onEvent(kind, JSON.parse(data));
    }
  }
}
