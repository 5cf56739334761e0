// The Navigation page's follow panel: the twin's robot follows the projected spot along the
// planned path (POST /paths/{id}/follow); its status, metrics and tracking error over time
// (uPlot) are shown live from the series GET /paths/{id} returns, and drawn on the plan.

import { api, poll } from "../../api.js";
import { busy } from "../../forms.js";
import { lineChart } from "../../chart.js";
import { fmt, h, mount, resultsTable, statusBadge, toastError } from "../../ui.js";

const POLL_MS = 500; // GET /paths/{id} while its follow task runs
const LAWS = [
  ["state_feedback", "State-error feedback"],
  ["adaptive", "Adaptive compensation"],
  ["proportional", "Proportional (baseline)"],
];

/** What the finished follow task measured. */
function metricsTable(result) {
  const mm = (v) => (v === null || v === undefined ? "–" : `${fmt(v * 1000, 1)} mm`);
  return resultsTable("follow-metrics", [
    ["RMS error", mm(result.rms_m), "follow-rms"],
    ["Max error", mm(result.max_m)],
    ["Steady (straight stretches)", mm(result.steady_m)],
    ["Finished drawing at", result.finish_s === null ? "never" : `${fmt(result.finish_s, 1)} s`],
    ["Spot lost", String(result.lost_events)],
    ["Drawing error (max)", mm(result.drawing_error_max_m)],
  ]);
}

/** The follow task's status line, its error and, once done, its metrics. */
function followFacts(follow) {
  const progress =
    follow.status === "running" && follow.progress !== null
      ? h(
          "span",
          { class: "small muted", testid: "follow-progress" },
          ` ${fmt(100 * follow.progress, 0)} %`,
        )
      : null;
  return [
    h(
      "p",
      null,
      "Follow task: ",
      statusBadge(follow.status, "follow-status"),
      follow.law
        ? h("span", { class: "small muted" }, ` ${follow.law}, seed ${follow.seed}`)
        : null,
      progress,
    ),
    follow.error
      ? h("p", { class: "small badge bad", testid: "follow-error" }, follow.error)
      : null,
    follow.result ? metricsTable(follow.result) : null,
  ];
}

/** The tracking error over time, one chart per run, fed the growing series while it runs. */
class ErrorChart {
  constructor() {
    this.box = h("div", { class: "nav-chart", testid: "nav-error-plot" });
    this.chart = null;
    this.key = null;
  }

  async show(follow, key) {
    const series = follow.series;
    if (!series || !series.t.length) return;
    const data = [series.t, series.error_m.map((e) => e * 1000)];
    try {
      if (this.chart && this.key === key) {
        this.chart.setData(data);
      } else {
        this.destroy();
        this.box.replaceChildren();
        this.key = key;
        this.chart = await lineChart(this.box, {
          title: `Tracking error, ${follow.law}`,
          x: "time (s)",
          y: "error (mm)",
          series: [{ label: "error (mm)", colour: "series-1" }],
          data,
        });
      }
      this.box.dataset.points = String(series.t.length);
      this.box.dataset.status = follow.status;
    } catch (err) {
      mount(this.box, h("p", { class: "small badge bad" }, err.message));
    }
  }

  destroy() {
    if (this.chart) this.chart.destroy();
    this.chart = null;
  }
}

/**
 * The follow panel's parts: a law to pick, the follow button, the task's facts and the error
 * chart; `drawRun(series, path)` draws the run on the plan. setPath(path | null) gives it the
 * path to follow. Returns {toolbar, box, chart, setPath, stop}.
 */
export function followView({ drawRun }) {
  const law = h(
    "select",
    { testid: "nav-law", "aria-label": "Control law" },
    LAWS.map(([v, label]) => h("option", { value: v }, label)),
  );
  const button = h(
    "button",
    { class: "btn primary", type: "button", testid: "nav-follow", disabled: true },
    "Follow on the twin",
  );
  const box = h("div", { testid: "nav-follow-box" });
  const chart = new ErrorChart();
  let path = null;
  let reads = null;

  const show = async (p) => {
    const follow = p.follow;
    mount(box, ...followFacts(follow));
    drawRun(follow.series, p);
    await chart.show(follow, `${p.id}:${follow.law}:${follow.started_at}`);
  };
  const stopReading = () => {
    reads?.stop();
    reads = null;
  };
  // GET /paths/{id} while its follow task runs.
  const follow = () => {
    stopReading();
    const id = path.id;
    reads = poll(() => api(`/paths/${id}`), {
      interval: POLL_MS,
      delay: true,
      stopOn4xx: true,
      onError: toastError,
      onValue: async (fresh) => {
        if (!path || fresh.id !== path.id) return false;
        path = fresh;
        await show(fresh);
        button.disabled = fresh.follow.status === "running" || !fresh.trajectory;
        return fresh.follow.status === "running";
      },
    });
  };
  button.addEventListener("click", async () => {
    if (!path) return;
    try {
      await busy(button, async () => {
        path = await api(`/paths/${path.id}/follow`, { method: "POST", json: { law: law.value } });
        await show(path);
      });
      button.disabled = true; // until the task ends
      follow();
    } catch (err) {
      toastError(err);
    }
  });

  return {
    toolbar: h("div", { class: "nav-toolbar" }, h("label", null, "Law ", law), button),
    box,
    chart: chart.box,
    setPath(next) {
      stopReading();
      path = next;
      button.disabled = !(next && next.trajectory);
      mount(box);
    },
    stop() {
      stopReading();
      chart.destroy();
    },
  };
}
