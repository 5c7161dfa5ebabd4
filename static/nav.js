// Shared console navigation. A page declares <header id="nav" data-page="NAME"></header>
// and loads this script; the header is built from PAGES so every page lists the same
// sections in the same order. Add a section here, nowhere else.
"use strict";
(() => {
  const PAGES = [
    ["rig", "Rig", "/rig.html"],
    ["live", "Live", "/live.html"],
    ["calibrate", "Calibrate", "/calibrate.html"],
    ["record", "Record", "/record.html"],
    ["subjects", "Subjects & recordings", "/subjects.html"],
    ["reports", "Reports", "/reports.html"],
    ["imu", "IMU", "/imu.html"],
    ["kscc", "KSCC", "/kscc.html"],
    // the clinician's guide; served without a login too (it holds no data)
    ["help", "Help", "/help.html"],
  ];
  function build() {
    const header = document.getElementById("nav");
    if (!header) return;
    const current = header.dataset.page;
    header.setAttribute("role", "banner");
    const brand = document.createElement("span");
    brand.className = "brand";
    brand.textContent = "gaitrig";
    const nav = document.createElement("nav");
    nav.setAttribute("aria-label", "Console sections");
    for (const [name, label, href] of PAGES) {
      const a = document.createElement("a");
      a.href = href;
      a.textContent = label;
      if (name === current) a.setAttribute("aria-current", "page");
      nav.append(a);
    }
    const view3d = document.createElement("a");
    view3d.id = "viewer-link";
    view3d.textContent = "3D view";
    view3d.target = "_blank";
    view3d.rel = "noopener";
    view3d.hidden = true;
    const logout = document.createElement("button");
    logout.className = "secondary";
    logout.id = "logout";
    logout.type = "button";
    logout.textContent = "Log out";
    logout.addEventListener("click", async () => {
      await fetch("/api/auth/logout", { method: "POST", credentials: "same-origin" }).catch(() => {});
      window.location.href = "/index.html";
    });
    // Hidden (its place kept: the header does not jump) until js/user-menu.js knows who is
    // logged in: a page open without a login (Help) offers "Log in" instead.
    logout.style.visibility = "hidden";
    // who is logged in, "Change password", "Accounts" for administrators: filled by
    // js/user-menu.js, loaded here so that every page has it
    const userMenu = document.createElement("div");
    userMenu.id = "user-menu";
    header.replaceChildren(brand, nav, view3d, userMenu, logout);
    // js/user-menu.js asks the server who is logged in (GET /api/auth/session, 200 for
    // nobody too) and says it with this event: {user: the user} when logged
    // in, {loggedOut: true} when nobody is, {user: null} when the server did not say.
    userMenu.addEventListener("gaitrig:user", (ev) => {
      const { user, loggedOut } = ev.detail;
      if (loggedOut) {
        const login = document.createElement("a");
        login.id = "login-link";
        login.href = "/index.html?next=" + encodeURIComponent(location.pathname + location.search + location.hash);
        login.textContent = "Log in";
        logout.replaceWith(login);
        return;
      }
      logout.style.visibility = "";
      // the 3D view's address is behind the login: asked only once there is one
      if (user) {
        fetch("/api/system", { credentials: "same-origin" })
          .then((r) => (r.ok ? r.json() : null))
          .then((sys) => { if (sys && sys.viewer_url) { view3d.href = sys.viewer_url; view3d.hidden = false; } })
          .catch(() => {});
      }
    }, { once: true });
    const menuScript = document.createElement("script");
    menuScript.src = "/js/user-menu.js";
    document.body.append(menuScript);
    // Keyboard users went through the ten header links on every page before reaching it:
    // the first Tab offers a jump to the page's own content.
    const main = document.querySelector("main");
    if (main) {
      if (!main.id) main.id = "main";
      main.tabIndex = -1;
      const skip = document.createElement("a");
      skip.className = "skip-link";
      skip.href = "#" + main.id;
      skip.textContent = "Skip to the page";
      skip.addEventListener("click", (ev) => { ev.preventDefault(); main.focus(); });
      header.before(skip);
    }
  }
  // The table's own name, else the heading it comes under; a second table under the same
  // heading is numbered (two regions of one name cannot be told apart).
  const tableNames = new Map();
  function tableName(table) {
    const by = table.getAttribute("aria-labelledby");
    const named = (by && document.getElementById(by.split(" ")[0])) || table.querySelector("caption");
    const above = [...document.querySelectorAll("main h1, main h2, main h3")]
      .filter((h) => h.compareDocumentPosition(table) & Node.DOCUMENT_POSITION_FOLLOWING).pop();
    const text = (table.getAttribute("aria-label") || (named || above || {}).textContent || "Table").trim();
    const n = (tableNames.get(text) || 0) + 1;
    tableNames.set(text, n);
    return `${text}${n > 1 ? ", table " + n : ""} (table, scrolls sideways)`;
  }
  // Reflow (WCAG 1.4.10): a data table wider than the window (a phone, a 400 % zoom) made
  // the whole page scroll sideways. Each table of <main> goes in a box that scrolls
  // instead; while it does, the box takes the keyboard focus (arrow keys scroll it) and is
  // a region named after its table, so a screen reader says what the stop is.
  function scrollBoxes() {
    for (const table of document.querySelectorAll("main table")) {
      if (table.closest(".table-scroll, .report-view")) continue;
      const box = document.createElement("div");
      box.className = "table-scroll";
      table.before(box);
      box.append(table);
      const name = tableName(table);
      const sync = () => {
        if (box.scrollWidth > box.clientWidth + 1) {
          box.tabIndex = 0;
          box.setAttribute("role", "region");
          box.setAttribute("aria-label", name);
        } else if (box.hasAttribute("tabindex")) {
          for (const a of ["tabindex", "role", "aria-label"]) box.removeAttribute(a);
        }
      };
      const watch = new ResizeObserver(sync);  // the window, and rows drawn into the table
      watch.observe(box);
      watch.observe(table);
    }
  }
  // Build at once when the header is already parsed (the script follows it), so page
  // scripts that run next find the header's elements.
  if (document.getElementById("nav") || document.readyState !== "loading") build();
  else document.addEventListener("DOMContentLoaded", build);
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", scrollBoxes);
  else scrollBoxes();
})();
