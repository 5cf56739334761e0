// Zones on the floor plan: each zone's polygon with its name and live occupancy (people counted
// by the service, spec 09), refreshed every second. Rooms are zones too (read-only, drawn by
// the plan already): only their counts are shown, at their centre.

import { api } from "./api.js";
import { s } from "./ui.js";

const ZONES_MS = 1000;

/** Return the mean of a polygon's vertices [[x, y], ...]. */
function centre(polygon) {
  const n = polygon.length || 1;
  return [
    polygon.reduce((a, p) => a + p[0], 0) / n,
    polygon.reduce((a, p) => a + p[1], 0) / n,
  ];
}

/** Draw the zones (GET /spaces/{id}/zones) into the SVG group g; return a stop function. */
export function drawZones(g, spaceIds, { X, Y }) {
  let stopped = false;
  let timer = null;
  const draw = (zones) => {
    g.replaceChildren();
    for (const z of zones) {
      const [cx, cy] = centre(z.polygon);
      const occupied = (z.occupancy || 0) > 0;
      const label = `${z.name}: ${z.occupancy ?? "–"}`;
      const testid = z.read_only ? `zone-room-${z.room_id}` : `zone-${z.id}`;
      const shape = z.read_only
        ? null
        : s("polygon", {
            class: `zone${occupied ? " occupied" : ""}`,
            points: z.polygon.map((p) => `${X(p[0]).toFixed(1)},${Y(p[1]).toFixed(1)}`).join(" "),
          });
      g.append(
        s(
          "g",
          { testid, "data-occupancy": z.occupancy ?? "", "data-slug": z.slug },
          shape,
          s(
            "text",
            {
              class: `zone-label${occupied ? " occupied" : ""}`,
              x: X(cx),
              y: Y(cy) + (z.read_only ? 14 : 0),
              "text-anchor": "middle",
            },
            z.read_only ? `👤 ${z.occupancy ?? "–"}` : label,
          ),
          s("title", null, `${label} (${z.read_only ? "room" : "zone"} ${z.slug})`),
        ),
      );
    }
  };
  const refresh = async () => {
    try {
      const all = await Promise.all(spaceIds.map((id) => api(`/spaces/${id}/zones`)));
      if (!stopped) draw(all.flat());
    } catch {
      // The plan stays as it was; the next refresh tries again.
    }
    if (!stopped) timer = setTimeout(refresh, ZONES_MS);
  };
  refresh();
  return () => {
    stopped = true;
    clearTimeout(timer);
  };
}
