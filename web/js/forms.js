// Forms: the fields every page's forms are built of, and one way to send a form, so each page
// writes only what it sends. A form sends once at a time (its button is disabled meanwhile) and
// shows what went wrong where the user looks: beside the form, or as a toast.

import { errorBox, h, mount, toastError } from "./ui.js";

/** Run `action()` with `button` disabled, so a second click cannot send the request again;
 * the button is enabled again whatever happened. Returns what `action` returns (or throws). */
export async function busy(button, action) {
  button.disabled = true;
  try {
    return await action();
  } finally {
    button.disabled = false;
  }
}

/**
 * Return the handler of a form's submit (or a button's click) that runs `action()` through
 * busy(`button`) (the clicked button when none is given). A failure is shown in `errors` as an
 * error box with `testid` (emptied first, unless `keep`), and as a toast too with `toast` or
 * when there is no `errors` box; a failure of the page's own (an Error without a problem's
 * title) is shown under `title`.
 */
export function sending(
  button,
  action,
  { errors, testid = "error", title, keep = false, toast = false } = {},
) {
  return async (event) => {
    event?.preventDefault();
    const target = button ?? event.currentTarget;
    if (errors && !keep) mount(errors);
    try {
      await busy(target, action);
    } catch (err) {
      const problem = err.title || !title ? err : { title, detail: err.message };
      if (errors) mount(errors, errorBox(problem, testid));
      if (toast || !errors) toastError(problem);
    }
  };
}

/** Return a button (type "button", `attrs` as h()'s) whose click sends `action()` as
 * sending() does with `options`. */
export function actionButton(attrs, label, action, options) {
  const button = h("button", { type: "button", ...attrs }, label);
  button.addEventListener("click", sending(button, action, options));
  return button;
}

/** Return the box a form's errors are shown in (read out when it changes). */
export function errorSlot() {
  return h("div", { "aria-live": "assertive" });
}

/** Return a field: `control` (an input or a select with id `id`) under its `label`. */
export function field(id, label, control, attrs = {}) {
  return h("label", { for: id, ...attrs }, label, control);
}

/** Return a row of a form: `label`, then `control` (id `id`) beside it. */
export function formRow(id, label, control) {
  return h("div", { class: "form-row" }, h("label", { for: id }, label), control);
}

/** Return a select of `choices` ([value, label] pairs), `selected` chosen; `attrs` as h()'s. */
export function choice(attrs, choices, selected) {
  return h(
    "select",
    attrs,
    choices.map(([value, label]) =>
      h(
        "option",
        { value: String(value), selected: selected != null && String(value) === String(selected) },
        label,
      ),
    ),
  );
}
