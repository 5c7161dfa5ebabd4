// Accounts page (administrators): the accounts with their role, creation, last login and
// whether the password is still a temporary one; create an account, set a new password
// for someone, remove an account with its name typed again (as a subject's deletion on
// the Subjects page); recent account changes from the audit trail in words. Every
// action's result is said in a live region. Data: /api/users, /api/auth/me, /api/audit.
"use strict";
(() => {
  const api = gaitrig.api;
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  function say(id, text, good = false) { const m = $(id); m.textContent = text; m.className = "msg " + (good ? "good" : "bad"); }
  // the API's times carry their offset (an older server's did not: read as UTC)
  const when = gaitrig.when;
  const dateText = (iso) => gaitrig.day(when(iso));
  const timeText = (iso) => gaitrig.dateTime(when(iso), { seconds: false });

  let me = null;

  function setPassword(u) {
    if (u.username === me.username)  // one's own goes through the dialog, which asks for the current one
      return el("button", { type: "button", class: "secondary small", onclick: () => { const b = $("password-open"); if (b) b.click(); } },
        "Change your password…");
    const input = el("input", { type: "password", autocomplete: "new-password", maxlength: "256", required: "",
      "aria-label": `new temporary password for ${u.username}` });
    const form = el("form", { class: "form-row", "aria-label": `Set a new password for ${u.username}` }, input,
      el("button", { type: "submit", class: "small" }, "Set password"));
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      try {
        await api(`/api/users/${encodeURIComponent(u.username)}/password`, { method: "POST", body: JSON.stringify({ new_password: input.value }) });
        await load().catch(() => {});  // first: the message then describes what is shown
        say("accounts-msg", `New password set for ${u.username}; their logins were ended. Give it to them yourself: the console asks them to choose their own.`, true);
        $("list-h").focus();  // the form was in the redrawn row
      } catch (e) { say("accounts-msg", `Password of ${u.username} not set: ${e.message}.`); }
    });
    return el("details", { class: "account-action" }, el("summary", {}, "Set a new password…"), form);
  }

  function remove(u) {
    const input = el("input", { autocomplete: "off", required: "", size: "12", "aria-label": `type ${u.username} to confirm`, placeholder: `type ${u.username}` });
    const form = el("form", { class: "form-row", "aria-label": `Remove the account ${u.username}` },
      el("label", {}, "Type the user name to confirm", input),
      el("button", { type: "submit", class: "danger small" }, "Remove account"));
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      try {
        await api(`/api/users/${encodeURIComponent(u.username)}/delete`, { method: "POST", body: JSON.stringify({ confirm: input.value.trim() }) });
        // the list redrawn first (the message then describes what is shown); the focus was
        // in the removed row: it goes to the list's heading
        await load().catch(() => {});
        say("accounts-msg", `Account ${u.username} removed; its logins were ended. The audit trail keeps its entries.`, true);
        $("list-h").focus();
      } catch (e) { say("accounts-msg", `Account ${u.username} not removed: ${e.message}.`); }
    });
    return el("details", { class: "danger-zone account-action" }, el("summary", {}, "Remove…"), form);
  }

  function row(u) {
    const you = u.username === me.username;
    const pw = u.must_change_password
      ? el("span", { class: "warn" }, u.password_set_by === "generated" ? "generated at the first start, not yet changed" : "temporary (set by an administrator)")
      : "chosen by its owner";
    return el("tr", { "data-user": u.username },
      el("th", { scope: "row", style: "overflow-wrap:anywhere" }, u.username, you ? el("span", { class: "hint" }, " (you)") : null),
      el("td", {}, u.is_admin ? "administrator" : "user"),
      el("td", {}, dateText(u.created_at)),
      el("td", {}, u.last_login_at ? timeText(u.last_login_at) : "never",
        u.open_logins ? el("span", { class: "hint" }, ` · ${u.open_logins} open`) : null),
      el("td", {}, pw),
      el("td", {}, setPassword(u), remove(u)));
  }

  // Requests overlap (an action's reload after another): only the last one asked draws.
  const seq = gaitrig.latest();
  async function load() {
    const mine = seq.ask();
    const users = await api("/api/users");
    if (!seq.current(mine)) return;
    $("accounts").replaceChildren(...users.map(row));
    await loadLog();
  }

  // The audit trail's account entries in words.
  function sentence(e) {
    const name = e.target.replace(/^user /, "");
    const d = e.detail || "";
    if (e.action === "password_change")
      return `${e.username} changed their own password` + (d ? ` (${d.replace(/login\(s\)/, /^1 /.test(d) ? "login" : "logins")})` : "") + ".";
    if (d.startsWith("created")) return `${e.username} created the account ${name}${d.includes("administrator") ? " (administrator)" : ""}.`;
    if (d === "removed") return `${e.username} removed the account ${name}.`;
    if (d.startsWith("password set")) {
      const ended = /(\d+) login/.exec(d);
      return `${e.username} set a new password for ${name}` + (ended ? `; ${gaitrig.plural(Number(ended[1]), "login")} of theirs ended` : "") + ".";
    }
    return `${e.username}: ${e.action} ${e.target} ${d}`.trim();
  }
  async function loadLog() {
    const box = $("account-log");
    try {
      const [a, b] = await Promise.all([api("/api/audit?action=account&limit=20"), api("/api/audit?action=password_change&limit=20")]);
      const items = [...a, ...b].sort((x, y) => y.id - x.id).slice(0, 20);
      box.replaceChildren(...items.map((e) => el("li", { "data-action": e.action },
        el("time", { datetime: when(e.at).toISOString() }, timeText(e.at)), " — ", sentence(e))));
      if (!items.length) box.replaceChildren(el("li", { class: "hint" }, "No account changes yet."));
    } catch (e) { box.replaceChildren(el("li", { class: "hint" }, "The audit trail could not be read: " + e.message)); }
  }

  $("create-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = ev.target.elements;
    const body = { username: f.username.value.trim(), password: f.password.value, is_admin: f.is_admin.checked };
    try {
      const u = await api("/api/users", { method: "POST", body: JSON.stringify(body) });
      ev.target.reset();
      await load().catch(() => {});
      say("create-msg", `Account ${u.username} created${u.is_admin ? " (administrator)" : ""}. Give them the temporary password yourself; they will be asked to choose their own.`, true);
    } catch (e) { say("create-msg", `Account not created: ${e.message}.`); }
  });

  (async () => {
    try { me = await api("/api/auth/me"); }
    catch (e) { $("accounts-loading").textContent = "Accounts could not be loaded: " + e.message; return; }
    $("accounts-loading").hidden = true;
    if (!me.is_admin) { $("not-admin").hidden = false; return; }
    $("admin-only").hidden = false;
    try { await load(); } catch (e) { say("accounts-msg", "The accounts could not be loaded: " + e.message); }
  })();
})();
