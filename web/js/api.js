// The service's REST API (/api/v1): bearer token from localStorage, problem-details errors.

const BASE = "/api/v1";
const TOKEN_KEY = "intspace.token";

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

export function getToken() {
  return localStorage.getItem(TOKEN_KEY) || "";
}

export function setToken(token) {
  if (token) localStorage.setItem(TOKEN_KEY, token);
  else localStorage.removeItem(TOKEN_KEY);
  window.dispatchEvent(new CustomEvent("auth-changed"));
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
 * options: {method, json, form, raw, checkingToken} - json is sent as a JSON body, form as
 * multipart; checkingToken: a 401 is the answer sought, not a sign that the session ended.
 */
export async function api(path, options = {}) {
  const headers = { Accept: "application/json" };
  const token = getToken();
  if (token) headers.Authorization = `Bearer ${token}`;
  let body;
  if (options.json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(options.json);
  } else if (options.form !== undefined) {
    body = options.form; // the browser sets the multipart boundary
  }
  let response;
  try {
    response = await fetch(BASE + path, { method: options.method || "GET", headers, body });
  } catch (err) {
    throw new Error(`The service did not answer (${err.message}). Is it running?`);
  }
  if (!response.ok) {
    const error = new ApiError(response.status, await problemFrom(response));
    if (response.status === 401 && !options.checkingToken) {
      window.dispatchEvent(new CustomEvent("auth-required"));
    }
    throw error;
  }
  if (options.raw) return response;
  if (response.status === 204) return null;
  const type = response.headers.get("content-type") || "";
  return type.includes("json") ? response.json() : response.text();
}

/** Return a list endpoint's items and total, whatever the page envelope looks like. */
export async function list(path, { limit = 200, offset = 0 } = {}) {
  const sep = path.includes("?") ? "&" : "?";
  const page = await api(`${path}${sep}limit=${limit}&offset=${offset}`);
  if (Array.isArray(page)) return { items: page, total: page.length };
  const items = page.items || page.data || [];
  return { items, total: page.total ?? items.length };
}

/** Download an authenticated resource as a file (a plain link would not send the token). */
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
