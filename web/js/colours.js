// The dashboard's colours are one table of CSS custom properties (the `:root` block of
// web/css/tokens.css). The stylesheet uses them by name; what the scripts paint (plots, the
// coverage heat map, legends) reads the same table here, so no colour is written twice.

const cache = new Map();

/** Return the colour of token `name` (without its `--`) as the stylesheet defines it. */
export function colour(name) {
  let value = cache.get(name);
  if (value === undefined) {
    value = getComputedStyle(document.documentElement).getPropertyValue(`--${name}`).trim();
    if (!value) throw new Error(`no colour token --${name} in tokens.css`);
    cache.set(name, value);
  }
  return value;
}

/** Return token `name`, a #rrggbb colour, as [r, g, b] (0..255), for painting pixels. */
export function channels(name) {
  const hex = colour(name);
  const m = /^#([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(hex);
  if (!m) throw new Error(`colour token --${name} is ${hex}, not #rrggbb`);
  return [1, 2, 3].map((i) => parseInt(m[i], 16));
}

/** Return `var(--name)`: a token for an inline style, resolved by the browser. */
export const cssVar = (name) => `var(--${name})`;
