"""``cellsim dashboard``: the cell in operation, in a terminal (Textual).

Panels, refreshed ``REFRESH`` times a second from the model (never per message):
the cell (safety modes, the safety controller's demands and notifications, the
process step and cycles), the hazards (phase, time in phase), the entities (twin
mode, link health OK/WARN/ERROR/STALE with the sample's age, twin and physical
values side by side, divergence highlighted), the robot (location, activity,
tool speed, true separation), the safety conditions over the trace so far, the
bridge daemon's diagnostics and the twin's pacing lag, and an event log.

Keys: ``m`` switches an entity's twin mode (choose the entity, the mode, then
confirm; the twin's answer goes to the event log), ``q`` quits. Levels are
written out as words as well as coloured, so ``NO_COLOR`` loses nothing.
"""

from __future__ import annotations

from rich.table import Table
from rich.text import Text
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.screen import ModalScreen
from textual.widgets import Footer, OptionList, RichLog, Static
from textual.widgets.option_list import Option

REFRESH = 4.0
"""Redraws per second."""
STYLE = {"OK": "green", "WARN": "yellow", "ERROR": "bold red", "STALE": "magenta", "-": "dim"}
MODES = ("model", "shadow", "twin")


def _table(title: str, *columns: str) -> Table:
    table = Table(title=title, title_justify="left", expand=True, box=None, padding=(0, 1), show_edge=False)
    for column in columns:
        table.add_column(column, overflow="ellipsis", no_wrap=True)
    return table


def _level(level: str) -> Text:
    return Text(level, style=STYLE.get(level, ""))


class ChoiceScreen(ModalScreen):
    """Pick one of some options (Escape: none)."""

    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, prompt: str, options: list[str]):
        super().__init__()
        self.prompt, self.options = prompt, options

    def compose(self) -> ComposeResult:
        with Vertical(id="dialog"):
            yield Static(self.prompt)
            yield OptionList(*[Option(o, id=o) for o in self.options])

    def on_option_list_option_selected(self, event: OptionList.OptionSelected) -> None:
        self.dismiss(event.option.id)


class ConfirmScreen(ModalScreen):
    """Yes or no (``y`` / ``n`` or Escape)."""

    BINDINGS = [Binding("y", "dismiss(True)", "yes"), Binding("n", "dismiss(False)", "no"),
                Binding("escape", "dismiss(False)", "no")]

    def __init__(self, question: str):
        super().__init__()
        self.question = question

    def compose(self) -> ComposeResult:
        with Vertical(id="dialog"):
            yield Static(f"{self.question}\n\n[y] yes   [n] no")


class Dashboard(App):
    """The dashboard of one cell, fed by a ``LiveFeed`` or a ``ReplayFeed``."""

    TITLE = "cellsim dashboard"
    # The cell and its hazards come first and keep their rows on a small terminal (80 x 24);
    # the panels below share what is left, and the event log keeps a few lines.
    CSS = """
    Screen { overflow: hidden; }
    #header { height: 1; background: $boost; }
    #top { height: auto; max-height: 10; }
    #top > Static { width: 1fr; }
    #entities { height: auto; max-height: 9; }
    #middle { height: 1fr; min-height: 0; overflow: hidden; }
    #middle > Static { width: 1fr; }
    RichLog { height: 6; border-top: solid $primary; }
    ChoiceScreen, ConfirmScreen { align: center middle; }
    #dialog { width: 60; height: auto; max-height: 20; border: thick $primary; background: $surface; padding: 1; }
    """
    BINDINGS = [Binding("m", "switch_mode", "switch a twin mode"), Binding("q", "quit", "quit")]

    def __init__(self, feed):
        super().__init__()
        self.feed = feed
        self._logged = 0

    def compose(self) -> ComposeResult:
        yield Static(id="header")
        with Horizontal(id="top"):
            yield Static(id="cell")
            yield Static(id="hazards")
        yield Static(id="entities")
        with Horizontal(id="middle"):
            yield Static(id="conditions")
            yield Static(id="robot")
            yield Static(id="links")
        yield RichLog(id="events", max_lines=500, markup=False)
        yield Footer()

    def on_mount(self) -> None:
        self.refresh_views()
        self.set_interval(1.0 / REFRESH, self.refresh_views)

    def refresh_views(self) -> None:
        try:
            self.feed.drain()
        except Exception as e:  # noqa: BLE001 - the network or a message: shown, never fatal
            self.query_one("#events", RichLog).write(f"feed error: {e}")
        model = self.feed.model
        header = self.query_one("#header", Static)
        if model is None:
            cell = getattr(self.feed, "cell", None)
            header.update(Text(f"cellsim dashboard: no twin running{' of ' + cell if cell else ''}; waiting for one ...",
                               style="bold"))
            return
        state = {"running": "twin running", "gone": "TWIN GONE", "waiting": "waiting for the twin",
                 "replay": f"replay of {self.feed.source}", "ended": f"replay of {self.feed.source} (ended)"}[model.twin]
        lag = (model.status or {}).get("lag")
        lag_text = f"  lag {lag * 1000:.1f} ms" if isinstance(lag, (int, float)) else ""
        header.update(Text(f"t = {model.sim_time:7.2f} s  |  {model.name}  |  {state}{lag_text}",
                           style="bold red" if model.twin == "gone" else "bold"))
        log = self.query_one("#events", RichLog)
        for view in (self._cell, self._hazards, self._entities, self._conditions, self._robot_and_links):
            try:
                view(model)
            except Exception as e:  # noqa: BLE001 - one panel's trouble is shown, never fatal
                model.log(f"cannot show {view.__name__.strip('_')}: {type(e).__name__}: {e}", "ERROR")
        new = min(model.event_count - self._logged, len(model.events))
        for event in list(model.events)[len(model.events) - new:]:
            log.write(Text(f"{event.sim_time:8.2f} s  {event.text}", style=STYLE.get(event.level, "")))
        self._logged = model.event_count

    def _cell(self, model) -> None:
        table = _table("cell", "", "")
        for name, value in model.cell_rows():
            table.add_row(name, value)
        self.query_one("#cell", Static).update(table)

    def _hazards(self, model) -> None:
        table = _table("hazards", "hazard", "phase", "for", "")
        for name, phase, since, level in model.hazard_rows():
            table.add_row(name, Text(phase, style=STYLE[level]), f"{since:.1f} s", _level(level))
        self.query_one("#hazards", Static).update(table)

    def _entities(self, model) -> None:
        table = _table("entities", "entity", "mode", "link", "age", "twin", "physical")
        for row in model.entity_rows():
            age = "-" if row["age"] is None else f"{row['age'] * 1000:.0f} ms"
            style = "bold yellow" if row["diverges"] else ""
            table.add_row(row["entity"], row["mode"], _level(row["level"]), age, Text(row["twin"], style=style),
                          Text(row["physical"] + (" (differs)" if row["diverges"] else ""), style=style))
        self.query_one("#entities", Static).update(table)

    def _conditions(self, model) -> None:
        table = _table("safety conditions (so far)", "condition", "verdict")
        for name, verdict, level in model.conditions():
            table.add_row(name, Text(verdict, style=STYLE.get(level, "")))
        self.query_one("#conditions", Static).update(table)

    def _robot_and_links(self, model) -> None:
        table = _table("robot", "", "")
        for name, value in model.robot_rows():
            table.add_row(name, value)
        self.query_one("#robot", Static).update(table)
        links = _table("bridge diagnostics", "device", "level", "rate", "errors")
        for device, status in sorted(model.diagnostics.items()):
            if device == "bridge":
                continue
            errors = sum(v for v in (status.get("counts") or {}).values() if isinstance(v, int))
            rate = status.get("rate_hz")
            links.add_row(device, _level(str(status.get("level"))), "-" if rate is None else f"{rate:.0f} Hz", str(errors))
        if len(links.rows) == 0:
            links.add_row("(no bridge daemon)", "", "", "")
        self.query_one("#links", Static).update(links)

    # -- interaction -----------------------------------------------------------------
    def action_switch_mode(self) -> None:
        model = self.feed.model
        if model is None or not hasattr(self.feed, "request_mode"):
            self.query_one("#events", RichLog).write("twin modes can be switched only on a running twin")
            return

        def chosen_entity(entity: str | None) -> None:
            if entity is None:
                return

            def chosen_mode(mode: str | None) -> None:
                if mode is None:
                    return

                def confirmed(yes: bool | None) -> None:
                    if yes:
                        self.request(entity, mode)

                self.push_screen(ConfirmScreen(f"Switch {entity} to {mode} mode?"), confirmed)

            self.push_screen(ChoiceScreen(f"{entity}: which mode?", list(MODES)), chosen_mode)

        self.push_screen(ChoiceScreen("Switch which entity's twin mode?", list(model.entities)), chosen_entity)

    @work(thread=True, exclusive=True)
    def request(self, entity: str, mode: str) -> None:
        """Ask the twin (off the interface's thread) and log its answer."""
        answer = self.feed.request_mode(entity, mode)
        verdict = "accepted" if answer.get("accepted") else "refused"
        level = "OK" if answer.get("accepted") else "ERROR"
        self.call_from_thread(self.feed.model.log, f"{entity} -> {mode}: {verdict}: {answer.get('reason', '')}", level)
