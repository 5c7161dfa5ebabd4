// The user menu of every console page, in the header nav.js builds (#user-menu): who is
// logged in, "Change password" (a dialog: current, new, repeat), "Accounts" for
// administrators only, and the suggestion to change a password someone else chose (the
// one generated at the first start, or a temporary one an administrator set). Loaded by
// nav.js, so no page lists it. Data: GET /api/auth/session, POST /api/auth/password.
"use strict";
(() => {
  const slot = document.getElementById("user-menu");
  if (!slot || slot.dataset.built) return;
  slot.dataset.built = "1";
  function el(tag, attrs = {}, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }
  const post = (path, body) => fetch(path, { method: "POST", credentials: "same-origin",
    headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  async function detail(r) {
    try { const d = (await r.json()).detail; return typeof d === "string" ? d : r.statusText; }
    catch (e) { return r.statusText; }
  }

  // How many other logins the change ended, in words (the server says how many since it
  // answers 200 with {"other_sessions_ended": n}; an older one answered 204 without it).
  function endedText(body) {
    const n = body && Number.isInteger(body.other_sessions_ended) ? body.other_sessions_ended : null;
    if (n === null) return "Your other logins (other browsers or computers) were ended; this one stays.";
    if (n === 0) return "You were not logged in anywhere else; this login stays.";
    return `${gaitrig.plural(n, "other login")} (other browsers or computers) ${n === 1 ? "was" : "were"} ended; this one stays.`;
  }

  // ---- the dialog: each refusal is said beside the field it is about
  // A refusal is the field's description (aria-describedby) and the field takes the focus:
  // a screen reader then says "Current password, invalid entry, Type your current
  // password." once, where the user types the fix. It is no live region: it was one too,
  // and was read twice (as news, then with the field). A field that has the focus already
  // (Enter pressed in it) is not announced again by a focus(), so there the refusal is
  // said by the dialog's one hidden live region (#pw-said) instead, still once.
  function field(id, label, autocomplete, hint) {
    const msg = el("p", { class: "field-msg", id: `${id}-msg` });
    const input = el("input", { id, name: id, type: "password", autocomplete, required: "",
      maxlength: "256", "aria-describedby": `${id}-msg${hint ? " " + id + "-hint" : ""}` });
    return { input, msg, box: el("div", { class: "field" }, el("label", { for: id }, label), input,
      hint ? el("p", { class: "hint", id: `${id}-hint` }, hint) : null, msg) };
  }
  let dialog = null, opener = null;
  function buildDialog(me) {
    const cur = field("pw-current", "Current password", "current-password");
    const nu = field("pw-new", "New password", "new-password",
      "At least 12 characters, not containing your user name; a few words make a good one.");
    const rep = field("pw-repeat", "New password again", "new-password");
    const status = el("p", { id: "pw-status", role: "status", class: "msg" });
    // (inside the dialog: a modal dialog hides the rest of the page from screen readers)
    const said = el("p", { id: "pw-said", role: "status", class: "sr-only" });
    const submit = el("button", { type: "submit", id: "pw-submit" }, "Change password");
    const close = el("button", { type: "button", class: "secondary", id: "pw-close" }, "Close");
    // the browser's password manager files the new password under this user name
    const who = el("input", { type: "text", name: "username", autocomplete: "username",
      value: me.username, hidden: "", readonly: "" });
    const form = el("form", { id: "password-form", novalidate: "" }, who, cur.box, nu.box, rep.box, status, said,
      el("div", { class: "actions" }, submit, close));
    dialog = el("dialog", { id: "password-dialog", "aria-labelledby": "password-h" },
      el("h2", { id: "password-h" }, `Change the password of ${me.username}`), form);
    document.body.append(dialog);
    let saidLast = "";
    const clear = () => {
      for (const f of [cur, nu, rep]) { f.msg.textContent = ""; f.input.removeAttribute("aria-invalid"); }
      saidLast = said.textContent; said.textContent = "";
    };
    const refuse = (f, text) => {
      f.msg.textContent = text; f.input.setAttribute("aria-invalid", "true");
      if (document.activeElement !== f.input) { f.input.focus(); return; }
      // the same refusal again (emptied and written in one task) would be no change to a
      // screen reader: a no-break space makes it one, and it is said again
      said.textContent = text === saidLast ? text + "\u00a0" : text;
    };
    close.addEventListener("click", () => dialog.close());
    // the focus goes back where it was (the menu's own button is hidden by then: its summary)
    dialog.addEventListener("close", () => {
      if (opener) opener.focus();
      if (menu && document.activeElement !== opener) menu.querySelector("summary").focus();
    });
    // Tab stays in the dialog: past its last field it goes round to the first (Chromium's
    // modal dialog let it leave the page, from where the next Tab began at the top).
    dialog.addEventListener("keydown", (ev) => {
      if (ev.key !== "Tab") return;
      const stops = [...dialog.querySelectorAll("input:not([hidden]), button")].filter((e) => !e.disabled);
      const first = stops[0], last = stops[stops.length - 1];
      if (ev.shiftKey && document.activeElement === first) { ev.preventDefault(); last.focus(); }
      else if (!ev.shiftKey && document.activeElement === last) { ev.preventDefault(); first.focus(); }
    });
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      clear();
      status.textContent = ""; status.className = "msg";
      if (!cur.input.value) return refuse(cur, "Type your current password.");
      if (!nu.input.value) return refuse(nu, "Type the new password.");
      if (nu.input.value !== rep.input.value) return refuse(rep, "The two new passwords differ: type the same one twice.");
      submit.disabled = true;
      try {
        const r = await post("/api/auth/password", { current_password: cur.input.value, new_password: nu.input.value });
        if (r.ok) {
          form.reset(); who.value = me.username;
          status.textContent = "Password changed. " + endedText(r.status === 204 ? null : await r.json().catch(() => null));
          status.className = "msg good";
          const banner = document.getElementById("password-banner");
          if (banner) banner.remove();
          close.focus();
          return;
        }
        const why = await detail(r);
        if (r.status === 401) { status.textContent = "Your login has ended: log in again, then change the password."; status.className = "msg bad"; }
        else if (r.status === 403) refuse(cur, why.charAt(0).toUpperCase() + why.slice(1) + ".");
        else if (r.status === 422) refuse(nu, "Not accepted: " + why + ".");
        else { status.textContent = "Not changed: " + why; status.className = "msg bad"; }
      } catch (e) {
        status.textContent = "Not changed: no answer from the server; check that it is running."; status.className = "msg bad";
      } finally {
        submit.disabled = false;
      }
    });
  }
  function openDialog() {
    // (the Accounts page's "Change your password…" clicks the menu's button for it)
    opener = document.activeElement;
    if (menu) menu.open = false;
    dialog.querySelector("#pw-status").textContent = "";
    dialog.showModal();
    dialog.querySelector("#pw-current").focus();
  }

  let menu = null;
  // nav.js shows "Log out" or "Log in" by what this finds (logged_in false: nobody, as on
  // the Help page opened from the login page; no answer: unknown, "Log out" stays)
  const say = (detail) => slot.dispatchEvent(new CustomEvent("gaitrig:user", { detail }));
  // GET /api/auth/session answers 200 for nobody too, so a logged-out page logs no
  // failed request in the browser's console
  fetch("/api/auth/session", { credentials: "same-origin" })
    .then((r) => (r.ok ? r.json() : null))
    .then((s) => {
      if (s && !s.logged_in) { say({ user: null, loggedOut: true }); return; }
      const me = s && s.user;
      if (!me) return;
      buildDialog(me);
      const change = el("button", { type: "button", class: "secondary", id: "password-open" }, "Change password");
      change.addEventListener("click", openDialog);
      const items = el("div", { class: "user-menu-items" },
        el("p", {}, `Logged in as ${me.username}${me.is_admin ? " (administrator)" : ""}.`), change);
      if (me.is_admin) {  // only administrators manage accounts: nobody else sees the link
        const a = el("a", { href: "/accounts.html", id: "accounts-link" }, "Accounts");
        const header = document.getElementById("nav");
        if (header && header.dataset.page === "accounts") a.setAttribute("aria-current", "page");
        items.append(a);
      }
      menu = el("details", { class: "user-menu" }, el("summary", { "aria-label": `Account: ${me.username}` }, me.username), items);
      // Escape or a click elsewhere closes the menu, as a menu does
      menu.addEventListener("keydown", (ev) => { if (ev.key === "Escape" && menu.open) { menu.open = false; menu.querySelector("summary").focus(); } });
      document.addEventListener("click", (ev) => { if (menu.open && !menu.contains(ev.target)) menu.open = false; });
      slot.replaceChildren(menu);
      say({ user: me, loggedOut: false });
      if (me.must_change_password) {
        const why = me.password_set_by === "generated"
          ? "You logged in with the password generated at the first start (it is in the server's log)."
          : "Your password was set by an administrator.";
        const now = el("button", { type: "button", class: "small" }, "Change password");
        now.addEventListener("click", openDialog);
        const banner = el("p", { id: "password-banner", class: "banner", role: "status" },
          `${why} Choose one only you know: `, now);
        const header = document.getElementById("nav");
        (header || slot).after(banner);
      }
    })
    .catch(() => {})
    // whatever happened, nav.js hears once (a later event is ignored there)
    .finally(() => say({ user: null, loggedOut: false }));
})();
