// Navigation: the floor plan paths are planned on (rooms, walls, furniture); click a start and
// a goal to plan a path (POST /paths), drawn by the chosen projector; follow it on the twin
// (POST /paths/{id}/follow) and watch, live, its status, the robot and the spot moving on the
// plan and the tracking error over time (uPlot), from the series GET /paths/{id} returns.

import { api, currentSpace, list, poll } from "../api.js";
import {
  drawFurniture,
  drawRooms,
  drawWalls,
  eventToWorld,
  planSvg,
  planTransform,
  pointsAttr,
  robotPose,
} from "../plan.js";
import { fmt, h, infoBox, mount, panel, s, statusBadge, toast, toastError } from "../ui.js";

const W = 900; // SVG user units across; the height follows the plan's aspect, at least 320
const POLL_MS = 500; // GET /paths/{id} while its follow task runs; GET a calibration run
const TERMINAL = new Set(["succeeded", "failed", "interrupted"]);
const LAWS = [
  ["state_feedback", "State-error feedback"],
  ["adaptive", "Adaptive compensation"],
  ["proportional", "Proportional (baseline)"],
];

let uplotLoading = null;

/** Load the vendored uPlot (web/vendor/uplot) once; resolve to its constructor. */
function loadUplot() {
  if (window.uPlot) return Promise.resolve(window.uPlot);
  if (!uplotLoading) {
    uplotLoading = new Promise((resolve, reject) => {
      const css = document.createElement("link");
      css.rel = "stylesheet";
      css.href = "vendor/uplot/uPlot.min.css";
      document.head.append(css);
      const script = document.createElement("script");
      script.src = "vendor/uplot/uPlot.iife.min.js";
      script.onload = () => resolve(window.uPlot);
      script.onerror = () => {
        uplotLoading = null;
        reject(new Error("the plotting library (vendor/uplot) did not load"));
      };
      document.head.append(script);
    });
  }
  return uplotLoading;
}

function metricsTable(result) {
  const row = (label, value, testid) =>
    h("tr", null, h("th", null, label), h("td", { class: "mono", testid }, value));
  const mm = (v) => (v === null || v === undefined ? "–" : `${fmt(v * 1000, 1)} mm`);
  return h(
    "table",
    { class: "nav-metrics", testid: "follow-metrics" },
    h(
      "tbody",
      null,
      row("RMS error", mm(result.rms_m), "follow-rms"),
      row("Max error", mm(result.max_m)),
      row("Steady (straight stretches)", mm(result.steady_m)),
      row("Finished drawing at", result.finish_s === null ? "never" : `${fmt(result.finish_s, 1)} s`),
      row("Spot lost", String(result.lost_events)),
      row("Drawing error (max)", mm(result.drawing_error_max_m)),
    ),
  );
}

/** What a finished projector calibration run found: its fit, and (the twin's own check) its
 * errors against the twin's true mount. */
function calibrationFacts(result) {
  const row = (label, value, testid) =>
    h("tr", null, h("th", null, label), h("td", { class: "mono", testid }, value));
  const e = result.twin_errors;
  return h(
    "table",
    { class: "nav-metrics", testid: "calib-result" },
    h(
      "tbody",
      null,
      row("Spots", String(result.spots), "calib-spots"),
      row("RMS floor error", `${fmt(result.rms_m * 1000, 1)} mm`, "calib-rms"),
      row("Tilt offset", `${fmt((result.tilt_offset_rad * 180) / Math.PI, 3)}°`),
      row(
        "Mount position",
        result.T_world_projector.slice(0, 3).map((r) => fmt(r[3], 3)).join(", ") + " m",
        "calib-position",
      ),
      row(
        "Uncertainty (one std)",
        `${fmt(result.position_std_m * 1000, 1)} mm, ${fmt(result.rotation_std_deg, 3)}°`,
      ),
      e
        ? row(
            "Against the twin",
            `${fmt(e.position_m * 1000, 1)} mm, ${fmt(e.rotation_deg, 3)}°`,
            "calib-twin-errors",
          )
        : null,
    ),
  );
}

export async function renderNavigation(main) {
  const space = currentSpace();
  if (!space) {
    mount(main, infoBox("No space yet: register a space and its rooms first.", "nav-empty"));
    return null;
  }
  // The space picked in the header.
  const spaceId = space.id;
  let plan = null;
  let projectors = [];
  let start = null;
  let goal = null;
  let path = null;
  let followPoll = null;
  let chart = null;
  let chartKey = null;
  let alive = true;

  const projectorSelect = h("select", { testid: "nav-projector", "aria-label": "Projector" });
  const calProjector = h("select", { testid: "calib-projector", "aria-label": "Projector to calibrate" });
  const calImages = h("input", { type: "checkbox", testid: "calib-images", checked: true });
  const calButton = h(
    "button",
    { class: "btn", type: "button", testid: "calib-start", disabled: true },
    "Calibrate projector",
  );
  const calBox = h("div", { testid: "calib-box", "aria-live": "polite" });
  // Why the calibration cannot start, when it cannot.
  const calWhy = h("p", { class: "small muted", testid: "calib-why", hidden: true });
  let calPoll = null;
  const lawSelect = h(
    "select",
    { testid: "nav-law", "aria-label": "Control law" },
    LAWS.map(([v, label]) => h("option", { value: v }, label)),
  );
  const followButton = h(
    "button",
    { class: "btn primary", type: "button", testid: "nav-follow", disabled: true },
    "Follow on the twin",
  );
  const hint = h("p", { class: "small muted", testid: "nav-hint" }, "Click the start on the plan.");
  const summary = h("div", { testid: "nav-summary" });
  const followBox = h("div", { testid: "nav-follow-box" });
  const chartBox = h("div", { class: "nav-chart", testid: "nav-error-plot" });
  const svgBox = h("div", { class: "nav-map" });
  const planBadge = h("span", { class: "badge", testid: "nav-floor-plan" });

  let tf = null;
  let gPath = null;
  let gRun = null;
  let gMarks = null;

  const drawMarks = () => {
    if (!gMarks) return;
    gMarks.replaceChildren();
    for (const [p, cls, label] of [
      [start, "nav-start", "start"],
      [goal, "nav-goal", "goal"],
    ]) {
      if (!p) continue;
      gMarks.append(
        s("circle", { class: cls, cx: tf.X(p[0]), cy: tf.Y(p[1]), r: 7, testid: `nav-${label}` }),
      );
    }
  };

  // The follow run so far on the plan: the robot's trail, the robot (its base radius, a tick
  // for its heading) and the laser spot, at the series' last sample.
  const drawRun = (series) => {
    if (!gRun) return;
    gRun.replaceChildren();
    if (!series || !series.t || !series.t.length || !series.x) return;
    const { X, Y } = tf;
    const k = series.t.length - 1;
    const trail = series.x.map((x, i) => [x, series.y[i]]);
    gRun.append(
      s("polyline", {
        class: "plan-trail",
        points: pointsAttr(trail, tf),
        testid: "nav-trail",
        "data-points": trail.length,
      }),
    );
    const [x, y, theta] = [series.x[k], series.y[k], series.theta[k]];
    const radius = path && path.robot_radius_m ? path.robot_radius_m : 0.2;
    gRun.append(
      robotPose(
        { x, y, theta },
        radius,
        tf,
        { testid: "nav-robot", "data-x": x, "data-y": y, "data-theta": theta, "data-t": series.t[k] },
        s("title", null, `robot at ${series.t[k].toFixed(1)} s`),
      ),
      s("circle", {
        class: "plan-spot",
        cx: X(series.spot_x[k]),
        cy: Y(series.spot_y[k]),
        r: 5,
        testid: "nav-spot",
        "data-x": series.spot_x[k],
        "data-y": series.spot_y[k],
      }),
    );
  };

  const drawPath = () => {
    if (!gPath) return;
    gPath.replaceChildren();
    if (gRun) gRun.replaceChildren();
    if (!path) return;
    if (path.trajectory) {
      gPath.append(
        s("polyline", {
          class: "nav-spot-path",
          points: pointsAttr(path.trajectory.spot, tf),
        }),
      );
    }
    gPath.append(
      s("polyline", {
        class: "nav-path",
        points: pointsAttr(path.points, tf),
        testid: "nav-path",
        "data-points": path.points.length,
      }),
    );
  };

  const drawPlan = () => {
    const extent = plan.rooms.flatMap((r) => r.polygon);
    tf = planTransform(extent.length ? extent : [[0, 0], [5, 4]], { width: W, minHeight: 320 });
    const svg = planSvg(tf, {
      className: "plot floormap nav-plan",
      label: "Floor plan: click a start, then a goal",
      testid: "nav-map",
    });
    const gRooms = s("g");
    const gObstacles = s("g");
    gPath = s("g");
    gRun = s("g");
    gMarks = s("g");
    svg.append(gRooms, gObstacles, gPath, gRun, gMarks);
    drawRooms(gRooms, plan.rooms, tf);
    drawWalls(gObstacles, plan.walls, tf);
    drawFurniture(gObstacles, plan.furniture, tf);
    svg.addEventListener("click", (ev) => {
      const w = eventToWorld(svg, tf, ev);
      if (!w) return;
      if (!start || goal) {
        start = w;
        goal = null;
        path = null;
        stopPolling();
        followButton.disabled = true;
        mount(summary);
        mount(followBox);
        hint.textContent = `Start (${fmt(w[0], 2)}, ${fmt(w[1], 2)}) m; click the goal.`;
        drawPath();
        drawMarks();
        return;
      }
      goal = w;
      drawMarks();
      planPath();
    });
    mount(svgBox, svg);
    drawPath();
    drawMarks();
  };

  const stopPolling = () => {
    followPoll?.stop();
    followPoll = null;
  };

  const showFollow = async (follow) => {
    const progress =
      follow.status === "running" && follow.progress !== null
        ? h("span", { class: "small muted", testid: "follow-progress" }, ` ${fmt(100 * follow.progress, 0)} %`)
        : null;
    mount(
      followBox,
      h(
        "p",
        null,
        "Follow task: ",
        statusBadge(follow.status, "follow-status"),
        follow.law ? h("span", { class: "small muted" }, ` ${follow.law}, seed ${follow.seed}`) : null,
        progress,
      ),
      follow.error ? h("p", { class: "small badge bad", testid: "follow-error" }, follow.error) : null,
      follow.result ? metricsTable(follow.result) : null,
    );
    drawRun(follow.series);
    if (follow.series && follow.series.t.length) {
      try {
        const uPlot = await loadUplot();
        if (!alive) return;
        const data = [follow.series.t, follow.series.error_m.map((e) => e * 1000)];
        // One chart per run, fed the growing series while it runs.
        const key = `${path ? path.id : ""}:${follow.law}:${follow.started_at}`;
        if (chart && chartKey === key) {
          chart.setData(data);
        } else {
          if (chart) chart.destroy();
          chartBox.replaceChildren();
          const width = Math.max(320, Math.min(chartBox.clientWidth || 860, 1000));
          chart = new uPlot(
            {
              width,
              height: 260,
              title: `Tracking error, ${follow.law}`,
              scales: { x: { time: false } },
              axes: [{ label: "time (s)" }, { label: "error (mm)" }],
              series: [{ label: "t (s)" }, { label: "error (mm)", stroke: "#2563eb", width: 1.5 }],
            },
            data,
            chartBox,
          );
          chartKey = key;
        }
        chartBox.dataset.points = String(follow.series.t.length);
        chartBox.dataset.status = follow.status;
      } catch (err) {
        mount(chartBox, h("p", { class: "small badge bad" }, err.message));
      }
    }
  };

  // GET /paths/{id} while its follow task runs.
  const followPath = () => {
    stopPolling();
    const id = path.id;
    followPoll = poll(() => api(`/paths/${id}`), {
      interval: POLL_MS,
      delay: true,
      onError: toastError,
      stopOn4xx: true,
      onValue: async (fresh) => {
        if (!path || fresh.id !== path.id) return false;
        path = fresh;
        await showFollow(fresh.follow);
        followButton.disabled = fresh.follow.status === "running" || !fresh.trajectory;
        return fresh.follow.status === "running";
      },
    });
  };

  const planPath = async () => {
    const body = { space_id: spaceId, start, goal };
    if (projectorSelect.value) body.projector_id = Number(projectorSelect.value);
    hint.textContent = "Planning…";
    try {
      path = await api("/paths", { method: "POST", json: body });
    } catch (err) {
      path = null;
      hint.textContent = "Click a new start.";
      mount(summary, h("p", { class: "small badge bad", testid: "nav-error" }, err.detail || err.message));
      drawPath();
      return;
    }
    hint.textContent = "Click a new start to plan another path.";
    const traj = path.trajectory;
    mount(
      summary,
      h(
        "p",
        null,
        "Path ",
        h("span", { class: "mono", testid: "nav-path-id" }, `#${path.id}`),
        ": ",
        h("strong", { testid: "nav-length" }, `${fmt(path.length_m, 2)} m`),
        ` through ${path.points.length - 2} bend(s)`,
        traj
          ? h(
              "span",
              { testid: "nav-duration" },
              `; the projector draws it in ${fmt(traj.duration_s, 1)} s at ${fmt(path.spot_speed_mps, 2)} m/s`,
            )
          : h("span", { class: "small muted" }, "; no projector chosen, nothing to follow"),
        ".",
      ),
    );
    followButton.disabled = !traj;
    mount(followBox);
    drawPath();
  };

  followButton.addEventListener("click", async () => {
    if (!path) return;
    followButton.disabled = true;
    try {
      path = await api(`/paths/${path.id}/follow`, { method: "POST", json: { law: lawSelect.value } });
      await showFollow(path.follow);
      followPath();
    } catch (err) {
      followButton.disabled = false;
      toastError(err);
    }
  });

  const loadSpace = async () => {
    stopPolling();
    start = goal = path = null;
    mount(summary);
    mount(followBox);
    followButton.disabled = true;
    const [drawing, pj] = await Promise.all([
      api(`/paths/floor-plan?space_id=${spaceId}`),
      list(`/projectors?space_id=${spaceId}`, { limit: 200 }),
    ]);
    plan = drawing;
    planBadge.textContent = `Floor plan: ${plan.floor_plan}`;
    fillProjectors(pj.items);
    const usable = projectors.find((p) => p.T_world_projector);
    if (usable) projectorSelect.value = String(usable.id);
    if (projectors.length) calProjector.value = String((usable || projectors[0]).id);
    mount(calBox);
    hint.textContent = "Click the start on the plan.";
    drawPlan();
  };

  // The space's projectors: those with a mount pose plan paths; any of them can be calibrated.
  function fillProjectors(items) {
    projectors = items;
    const planning = projectorSelect.value;
    const calibrating = calProjector.value;
    projectorSelect.replaceChildren(
      h("option", { value: "" }, "No projector"),
      ...projectors.map((p) =>
        h(
          "option",
          { value: p.id, disabled: !p.T_world_projector },
          p.T_world_projector ? p.name : `${p.name} (uncalibrated)`,
        ),
      ),
    );
    calProjector.replaceChildren(
      ...projectors.map((p) =>
        h("option", { value: p.id }, p.T_world_projector ? p.name : `${p.name} (uncalibrated)`),
      ),
    );
    if (projectors.some((p) => String(p.id) === planning && p.T_world_projector))
      projectorSelect.value = planning;
    if (projectors.some((p) => String(p.id) === calibrating)) calProjector.value = calibrating;
    calButton.disabled = !projectors.length;
    calWhy.hidden = projectors.length > 0;
    calWhy.textContent = projectors.length
      ? ""
      : `No projector is registered in ${space.name}: register it (POST /api/v1/projectors ` +
        "with this space's id) to calibrate it here. The digital twin registers its own " +
        "projector in its home when the service runs with INTSPACE_SIMULATION=true.";
  }

  // Projector calibration on the twin: a run of kind "projector" (POST /calibration-runs),
  // polled until it ends; a succeeded run can be applied here (POST .../apply), which gives
  // the projector its new mount for the paths planned next and in the 3D scene.
  const showRun = (run) => {
    const p = run.progress;
    const pct = p ? Math.round(100 * p.fraction) : 0;
    const applyButton =
      run.status === "succeeded" && run.result
        ? h(
            "button",
            {
              class: "btn primary",
              type: "button",
              testid: "calib-apply",
              onClick: async (ev) => {
                const btn = ev.currentTarget;
                btn.disabled = true;
                try {
                  const applied = await api(`/calibration-runs/${run.id}/apply`, { method: "POST" });
                  btn.textContent = "Applied";
                  toast(`Calibration applied to projector ${applied.name}`);
                  const pj = await list(`/projectors?space_id=${spaceId}`, { limit: 200 });
                  if (!alive) return;
                  fillProjectors(pj.items);
                  if (!projectorSelect.value) projectorSelect.value = String(applied.id);
                  calBox.dataset.applied = String(run.id);
                } catch (err) {
                  btn.disabled = false;
                  toastError(err);
                }
              },
            },
            `Apply to ${projectors.find((p) => p.id === run.result.projector_id)?.name ?? `projector #${run.result.projector_id}`}`,
          )
        : null;
    mount(
      calBox,
      h(
        "p",
        null,
        "Run ",
        h("a", { href: `#/calibration/runs/${run.id}`, class: "mono", testid: "calib-run" }, `#${run.id}`),
        ": ",
        statusBadge(run.status, "calib-status"),
        run.status === "running" && p
          ? h("span", { class: "small muted", testid: "calib-progress" }, ` ${p.stage}: ${pct} %`)
          : null,
      ),
      run.error ? h("p", { class: "small badge bad", testid: "calib-error" }, run.error) : null,
      run.status === "succeeded" && run.result ? calibrationFacts(run.result) : null,
      applyButton ? h("div", { class: "form-actions" }, applyButton) : null,
    );
  };

  // GET /calibration-runs/{id} until the run ends.
  const followRun = (id) => {
    calPoll?.stop();
    calPoll = poll(() => api(`/calibration-runs/${id}`), {
      interval: POLL_MS,
      delay: true,
      stopOn4xx: true, // a refusal will not change; keep trying while the service is unreachable
      onValue: (run) => {
        showRun(run);
        if (!TERMINAL.has(run.status)) return true;
        calButton.disabled = false;
        return false;
      },
      onError: (err) => {
        toastError(err);
        if (err.status >= 400 && err.status < 500) calButton.disabled = false;
      },
    });
  };

  calButton.addEventListener("click", async () => {
    if (!calProjector.value) return;
    calButton.disabled = true;
    calPoll?.stop();
    try {
      const run = await api("/calibration-runs", {
        method: "POST",
        json: { kind: "projector", projector_id: Number(calProjector.value), images: calImages.checked },
      });
      showRun(run);
      followRun(run.id);
    } catch (err) {
      calButton.disabled = false;
      mount(calBox, h("p", { class: "small badge bad", testid: "calib-error" }, err.detail || err.message));
    }
  });
  await loadSpace();

  mount(
    main,
    panel(
      "Plan",
      "Click a start, then a goal: the path keeps the robot's radius plus 5 cm from walls and " +
        "furniture; with a projector, the service also plans the beam's joint trajectory.",
      h(
        "div",
        { class: "nav-toolbar" },
        h("label", null, "Projector ", projectorSelect),
        planBadge,
      ),
      svgBox,
      hint,
      summary,
    ),
    panel(
      "Projector calibration",
      "The twin's projector points its beam at spots over the floor; the space's calibrated " +
        "ceiling cameras locate each spot and the projector's mount is fitted to them. Apply " +
        "the result to plan with the new mount.",
      h(
        "div",
        { class: "nav-toolbar" },
        h("label", null, "Projector ", calProjector),
        h("label", null, calImages, " Detect the spots in rendered images (about 10 s)"),
        calButton,
      ),
      calWhy,
      calBox,
    ),
    panel(
      "Follow",
      "The twin's robot follows the projected spot with its floor camera (15 Hz, 100 ms " +
        "latency); the error is the distance from its control point to the spot. While it " +
        "runs, the robot (green, with its trail) and the spot (red) move on the plan.",
      h("div", { class: "nav-toolbar" }, h("label", null, "Law ", lawSelect), followButton),
      followBox,
      chartBox,
    ),
  );
  return () => {
    alive = false;
    stopPolling();
    calPoll?.stop();
    if (chart) chart.destroy();
  };
}
