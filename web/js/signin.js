// The header's sign-in: who is signed in (and with which scopes) with a Sign out button, or the
// form that sends an access token once. The service then sets the session cookie.

import { currentSession, signIn, signOut } from "./api.js";
import { h, mount } from "./ui.js";

/** Draw the header's sign-in box for the current session; `notice` says why a session ended. */
export function renderAuth(notice = "") {
  const box = document.getElementById("auth");
  const session = currentSession();
  if (session.authenticated) {
    const scope = (session.scopes || []).join(", ");
    mount(
      box,
      h(
        "span",
        { class: "who", testid: "auth-status", title: session.name || "" },
        h("span", { class: "dot ok", "aria-hidden": "true" }),
        scope ? `Signed in (${scope})` : "Signed in",
      ),
      h(
        "button",
        {
          class: "btn small",
          type: "button",
          testid: "sign-out",
          onClick: () => signOut().catch(() => {}),
        },
        "Sign out",
      ),
    );
    return;
  }
  const input = h("input", {
    type: "password",
    id: "token-input",
    name: "token",
    autocomplete: "current-password",
    placeholder: "Access token",
    "aria-label": "Access token",
    required: true,
    testid: "token-input",
  });
  // Password managers expect a user name next to a password field; the token has none.
  const user = h("input", {
    type: "text",
    name: "username",
    autocomplete: "username",
    value: "token",
    hidden: true,
    "aria-hidden": "true",
    tabindex: "-1",
  });
  const status = h(
    "span",
    { class: notice ? "small badge bad" : "small muted", testid: "auth-status" },
    notice || "Not signed in",
  );
  const form = h(
    "form",
    {
      testid: "token-form",
      onSubmit: async (ev) => {
        ev.preventDefault();
        const token = input.value.trim();
        if (!token) return;
        // The token goes to the service once, in a POST body; the page keeps only the cookie
        // the service sets (which it cannot read) and the session's CSRF token.
        try {
          await signIn(token);
        } catch (err) {
          status.textContent =
            err.status === 401 || err.status === 403 ? "Token refused" : err.message;
          status.className = "small badge bad";
          input.select();
        }
      },
    },
    user,
    input,
    h("button", { class: "btn primary small", type: "submit", testid: "token-submit" }, "Sign in"),
  );
  mount(box, status, form);
}
