// The service's REST API (/api/v1): the dashboard signs in once with a token (POST /session),
// after which an HttpOnly SameSite=Strict cookie the page cannot read carries the session, and
// every write sends the session's CSRF token. No token is kept by the page: not in storage,
// not in a URL.

const BASE = "/api/v1";
const SAFE = new Set(["GET", "HEAD", "OPTIONS"]);

/** Return the address of the service's `path` ("/landmarks/3/print.svg"), for a link the
 * browser follows itself with the session cookie. */
export const apiUrl = (path) => BASE + path;

/** An HTTP error carrying the service's problem-details body ({type,title,status,detail,errors}). */
export class ApiError extends Error {
  constructor(status, problem) {
    const title = problem.title || `HTTP ${status}`;
    super(problem.detail ? `${title}: ${problem.detail}` : title);
    this.name = "ApiError";
    this.status = status;
    this.title = title;
    this.detail = problem.detail || "";
    this.errors = Array.isArray(problem.errors) ? problem.errors : [];
  }
}

// What GET /session said: {authenticated, name, scopes, csrf_token, public_reads}.
let session = { authenticated: false };

/** Return the dashboard's session as the service last described it. */
export function currentSession() {
  return session;
}

function setSession(next, notify = true) {
  session =
    next && next.authenticated
      ? next
      : { authenticated: false, public_reads: !!next?.public_reads };
  if (notify) window.dispatchEvent(new CustomEvent("auth-changed"));
}

/** Ask the service who this browser is (the cookie is sent, never read). */
export async function loadSession() {
  try {
    setSession(await api("/session", { checkingToken: true }), false);
  } catch {
    setSession(null, false);
  }
  return session;
}

/** Sign in with a token: the service answers with the session cookie and its CSRF token. */
export async function signIn(token) {
  const state = await api("/session", { method: "POST", json: { token }, checkingToken: true });
  setSession(state);
  return state;
}

/** Sign out: the service ends the session and removes its cookie. */
export async function signOut() {
  try {
    await api("/session", { method: "DELETE", checkingToken: true });
  } finally {
    setSession(null);
  }
}

async function problemFrom(response) {
  const type = response.headers.get("content-type") || "";
  if (type.includes("json")) {
    try {
      const body = await response.json();
      // FastAPI's own errors use {"detail": ...}; keep whatever the server said.
      if (typeof body.detail !== "string" && body.detail !== undefined && !body.title) {
        return { title: response.statusText, detail: JSON.stringify(body.detail) };
      }
      return body;
    } catch {
      /* fall through to the status line */
    }
  } else {
    const text = (await response.text()).trim();
    if (text) return { title: response.statusText, detail: text.slice(0, 300) };
  }
  return { title: response.statusText || `HTTP ${response.status}` };
}

/**
 * Call the API and return the decoded JSON (null for 204). Throws ApiError on any non-2xx,
 * and a plain Error with a readable message when the service cannot be reached.
 * options: {method, json, form, raw, accept, checkingToken} - json is sent as a JSON body, form
 * (a FormData or the fields formData() takes) as multipart; raw: return the Response itself
 * (an image, a file); accept: the media type asked for (JSON by default); checkingToken: a 401
 * is the answer sought, not a sign that the session ended.
 * Writes carry the session's CSRF token (X-CSRF-Token).
 */
export async function api(path, options = {}) {
  const method = (options.method || "GET").toUpperCase();
  const headers = { Accept: options.accept || "application/json" };
  if (!SAFE.has(method) && session.csrf_token) headers["X-CSRF-Token"] = session.csrf_token;
  let body;
  if (options.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(options.json);
  } else if (options.form !== undefined) {
    // The browser sets the multipart boundary.
    body = options.form instanceof FormData ? options.form : formData(options.form);
  }
  let response;
  try {
    response = await fetch(BASE + path, { method, headers, body, credentials: "same-origin" });
  } catch (err) {
    throw new Error(`The service did not answer (${err.message}). Is it running?`);
  }
  if (!response.ok) {
    const error = new ApiError(response.status, await problemFrom(response));
    if (response.status === 401 && !options.checkingToken) {
      const wasSignedIn = session.authenticated;
      if (wasSignedIn) setSession(null, false);
      window.dispatchEvent(new CustomEvent("auth-required", { detail: { wasSignedIn } }));
    }
    throw error;
  }
  if (options.raw) return response;
  if (response.status === 204) return null;
  const type = response.headers.get("content-type") || "";
  return type.includes("json") ? response.json() : response.text();
}

/** Return a multipart body of `fields`: {name: value}, a value a string, a number, a File or a
 * list of Files (each appended under the name with its own file name). */
export function formData(fields) {
  const body = new FormData();
  for (const [name, value] of Object.entries(fields)) {
    if (value === null || value === undefined) continue;
    const values = value instanceof FileList || Array.isArray(value) ? [...value] : [value];
    for (const v of values) {
      if (v instanceof File) body.append(name, v, v.name);
      else body.append(name, String(v));
    }
  }
  return body;
}

// -- polling -------------------------------------------------------------------------------------
// Every page that follows something live asks the service again and again. One loop does it for
// all of them: one request at a time, slower after failures, and stopped when the page is left.

const polls = new Set();

/**
 * Call `request()` now (or after `interval` ms with `delay`) and again `interval` ms after each
 * answer, until stopped; `onValue(value)` is given each answer and returning false stops it
 * (the thing followed is done). A failure goes to `onError(err)`, and the next try waits twice
 * as long each time (up to `maxInterval`); a refusal (4xx) will not change, so it stops the
 * poll when `stopOn4xx`. Requests never overlap. Every poll stops when the page is left
 * (leavePage()), but one the whole dashboard keeps (`keep`). Returns {stop(), now()}: now() asks again at once, or right after the request
 * in flight.
 */
export function poll(
  request,
  {
    interval,
    maxInterval = 8 * interval,
    onValue,
    onError,
    stopOn4xx = false,
    delay = false,
    keep = false,
  },
) {
  let stopped = false;
  let timer = null;
  let inFlight = false;
  let again = false;
  let wait = interval;
  const handle = {
    stop() {
      stopped = true;
      clearTimeout(timer);
      polls.delete(handle);
    },
    now() {
      if (stopped) return;
      if (inFlight) again = true;
      else {
        clearTimeout(timer);
        tick();
      }
    },
  };
  const schedule = (ms) => {
    if (!stopped) timer = setTimeout(tick, ms);
  };
  async function tick() {
    timer = null;
    inFlight = true;
    let goOn = true;
    try {
      const value = await request();
      if (stopped) return;
      wait = interval;
      goOn = onValue ? (await onValue(value)) !== false : true;
    } catch (err) {
      if (stopped) return;
      wait = Math.min(2 * wait, maxInterval);
      onError?.(err);
      if (stopOn4xx && err.status >= 400 && err.status < 500) goOn = false;
    } finally {
      inFlight = false;
    }
    if (stopped) return;
    if (!goOn) handle.stop();
    else if (again) {
      again = false;
      tick();
    } else schedule(wait);
  }
  if (!keep) polls.add(handle);
  if (delay) schedule(interval);
  else tick();
  return handle;
}

/** Stop every poll the page started: called by the router when the page is left. */
export function leavePage() {
  for (const handle of [...polls]) handle.stop();
}

/** Settle `promise`: {value} when it resolves, {error} when it rejects, so a page can show
 * what it read beside what failed. */
export function settled(promise) {
  return promise.then(
    (value) => ({ value }),
    (error) => ({ error }),
  );
}

/** Return a list endpoint's items and total, whatever the page envelope looks like. */
export async function list(path, { limit = 200, offset = 0 } = {}) {
  const sep = path.includes("?") ? "&" : "?";
  const page = await api(`${path}${sep}limit=${limit}&offset=${offset}`);
  if (Array.isArray(page)) return { items: page, total: page.length };
  const items = page.items || page.data || [];
  return { items, total: page.total ?? items.length };
}

/** Download an authenticated resource as a file (saved under `filename`, not the URL's name). */
export async function download(path, filename) {
  const response = await api(path, { raw: true });
  const blob = await response.blob();
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

// -- the space the dashboard shows -----------------------------------------------------------
// The chosen space's id is remembered in this browser (localStorage holds that number only);
// every page reads its devices, targets and maps for that space.

const SPACE_KEY = "intspace.space";
let spaces = [];
let space = null;

function storedSpaceId() {
  try {
    return Number(localStorage.getItem(SPACE_KEY)) || null;
  } catch {
    return null; // storage disabled: the first space each time
  }
}

/** Read the spaces (again) and resolve the chosen one: the remembered id while it exists, else
 * the first space. Returns {spaces, space}; no spaces (or reads refused) gives {[], null}. */
export async function loadSpaces() {
  try {
    // A refusal is for the page to report (it reads the registry too).
    const page = await api("/spaces?limit=200&offset=0", { checkingToken: true });
    spaces = page.items || [];
  } catch {
    spaces = [];
  }
  const wanted = space?.id ?? storedSpaceId();
  space = spaces.find((sp) => sp.id === wanted) || spaces[0] || null;
  return { spaces, space };
}

/** Return the chosen space ({id, name, description}) or null when there is none. */
export function currentSpace() {
  return space;
}

/** Choose the space the pages show and remember it in this browser; pages are told. */
export function chooseSpace(id) {
  const next = spaces.find((sp) => sp.id === Number(id));
  if (!next) return;
  space = next;
  try {
    localStorage.setItem(SPACE_KEY, String(next.id));
  } catch {
    /* not remembered: the choice holds until the page is reloaded */
  }
  window.dispatchEvent(new CustomEvent("space-changed"));
}

/**
 * Return `path` scoped to the chosen space: `space_id=N`, and with `unassigned` the devices of
 * no space too (a device list); unchanged when there is no space yet.
 */
export function inSpace(path, { unassigned = false } = {}) {
  if (!space) return path;
  const sep = path.includes("?") ? "&" : "?";
  return `${path}${sep}space_id=${space.id}${unassigned ? "&unassigned=true" : ""}`;
}

/** Return the space with this id among those last read, or null. */
export function spaceById(id) {
  return spaces.find((sp) => sp.id === id) || null;
}
