// A camera's intrinsics as a list of facts: K's entries and the distortion, each with its
// standard deviation when the calibration gave one.

import { fmt, h, sig } from "../../ui.js";

const DIST_NAMES = ["k1", "k2", "p1", "p2", "k3"];

function stdOf(std, name, index) {
  if (!std) return null;
  if (Array.isArray(std)) return std[index];
  return std[name];
}

/** The intrinsics as a list: value ± standard deviation; K's entries in pixels to 3 decimals,
 * the distortion coefficients to 6 significant digits. */
export function intrinsicsFacts(K, dist, std, testPrefix) {
  const fact = (name, value, sd, unit) => [
    h("dt", null, name),
    h(
      "dd",
      { class: "num", testid: `${testPrefix}-${name}` },
      value,
      sd ? h("span", { class: "muted" }, ` ± ${sd}`) : null,
      unit,
    ),
  ];
  const entries = [
    ["fx", K[0][0]],
    ["fy", K[1][1]],
    ["cx", K[0][2]],
    ["cy", K[1][2]],
    ["skew", K[0][1]],
  ];
  const rows = entries.map(([name, v], i) => {
    const sd = stdOf(std, name, i);
    return fact(name, fmt(v, 3), sd ? fmt(sd, 3) : null, " px");
  });
  const distRows = (dist || []).map((v, i) => {
    const name = DIST_NAMES[i] || `d${i}`;
    const sd = stdOf(std, name, 5 + i);
    return fact(name, sig(v, 6), sd ? sig(sd, 2) : null, null);
  });
  return h("dl", { class: "facts", testid: `${testPrefix}-intrinsics` }, rows, distRows);
}
