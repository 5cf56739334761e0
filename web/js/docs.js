// The API documentation page: Swagger UI from the package, reading the service's OpenAPI.
// "Try it out" works with a bearer token (the Authorize button) or the dashboard's sign-in,
// whose writes carry the session's CSRF token like the dashboard's do.

(function () {
  const root = document.getElementById("swagger-ui");
  let csrf = null;
  fetch("/api/v1/session", { headers: { Accept: "application/json" } })
    .then((r) => (r.ok ? r.json() : null))
    .then((s) => {
      csrf = s && s.csrf_token ? s.csrf_token : null;
    })
    .catch(() => {});
  window.ui = SwaggerUIBundle({
    url: root.dataset.openapiUrl,
    dom_id: "#swagger-ui",
    deepLinking: true,
    presets: [SwaggerUIBundle.presets.apis],
    layout: "BaseLayout",
    requestInterceptor: (req) => {
      const method = (req.method || "GET").toUpperCase();
      if (csrf && !["GET", "HEAD", "OPTIONS"].includes(method)) req.headers["X-CSRF-Token"] = csrf;
      return req;
    },
  });
})();
