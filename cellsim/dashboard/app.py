"""``cellsim dashboard``: the cell in operation, in a terminal (Textual).

Panels, refreshed ``REFRESH`` times a second from the model (never per message):
the cell (safety modes, the safety controller's demands and notifications, the
process step and cycles), the hazards (phase, time in phase), the entities (twin
mode, link health OK/WARN/ERROR/STALE with the sample's age, twin and physical
values side by side, divergence highlighted), the robot (location, activity,
tool speed, true separation), the safety conditions over the trace so far, the
bridge daemon's diagnostics and the twin's pacing lag, and an event log.

Keys: ``m`` switches an entity's twin mode (choose the entity, then the mode, by
number or arrows and Enter, then confirm with ``y``; the twin's answer goes to the
event log), ``q`` quits. Levels are
written out as words as well as coloured, so ``NO_COLOR`` loses nothing.
"""

from __future__ import annotations

from rich.text import Text
from textual import work
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical, VerticalScroll
from textual.css.query import NoMatches
from textual.screen import ModalScreen
from textual.widget import Widget
from textual.widgets import Footer, OptionList, RichLog, Static
from textual.widgets.option_list import Option

REFRESH = 4.0
"""Redraws per second."""
STYLE = {"OK": "green", "WARN": "yellow", "ERROR": "bold red", "STALE": "magenta", "-": "dim"}
MODES = ("model", "shadow", "twin")


def _grid(title: str, columns: tuple[str, ...], rows: list[tuple], room: int | None = None) -> Text:
    """A table as plain text in columns: rich's Table measures and wraps every cell on every
    redraw (milliseconds a panel), this is one pass. A cell is a string or (string, style).

    ``room``: the panel's width in characters; the last column is cut to fit it, and left
    out when fewer than 12 characters would be left for it."""
    cells = [[c if isinstance(c, tuple) else (str(c), "") for c in row] for row in rows]
    widths = [max([len(columns[i])] + [len(row[i][0]) for row in cells]) for i in range(len(columns))]
    widths = [min(w, 40) for w in widths]
    if room is not None:
        left = room - sum(w + 1 for w in widths[:-1]) - 1
        if left < 12:
            columns, widths, cells = columns[:-1], widths[:-1], [row[:-1] for row in cells]
        else:
            widths[-1] = min(widths[-1], left)
    text = Text(title, style="bold")
    text.append("\n " + " ".join(h.ljust(w) for h, w in zip(columns, widths)).rstrip(), style="dim")
    for row in cells:
        text.append("\n")
        for (value, style), width in zip(row, widths):
            value = value if len(value) <= width else value[: width - 1] + "…"
            text.append(" ")
            text.append(value.ljust(width), style=style)
    text.no_wrap, text.overflow = True, "ellipsis"
    return text


def _level(level: str) -> tuple[str, str]:
    return level, STYLE.get(level, "")


class Panel(Widget):
    """A panel whose height is its number of lines: a new content repaints it alone, and the screen is
    laid out again only when that height changes (a Static lays the whole screen out on every update)."""

    def __init__(self, id: str):  # noqa: A002 - Textual's name
        super().__init__(id=id)
        self._renderable = Text("")
        self._lines = 0

    def render(self):
        return self._renderable

    def show(self, renderable, lines: int) -> None:
        self._renderable = renderable
        if lines != self._lines:
            self._lines = lines
            self.styles.height = lines
        self.refresh()


class ChoiceScreen(ModalScreen):
    """Pick one of some options: its number key, or the arrows and Enter (Escape: none)."""

    BINDINGS = [Binding("escape", "dismiss(None)", "cancel")]

    def __init__(self, prompt: str, options: list[str]):
        super().__init__()
        self.prompt, self.options = prompt, options

    def compose(self) -> ComposeResult:
        with Vertical(id="dialog"):
            yield Static(self.prompt)
            yield OptionList(*[Option(f"{i + 1}  {o}", id=o) for i, o in enumerate(self.options)])

    def on_mount(self) -> None:
        self.query_one(OptionList).focus()

    def on_key(self, event) -> None:
        if event.character and event.character.isdigit() and 1 <= int(event.character) <= min(9, len(self.options)):
            event.stop()
            self.dismiss(self.options[int(event.character) - 1])

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


class ConditionsScreen(ModalScreen):
    """Every safety condition in full: its verdict so far, what it means, and why it is violated
    (``c`` or Escape closes it)."""

    BINDINGS = [Binding("escape", "dismiss", "close"), Binding("c", "dismiss", "close")]

    def __init__(self, text: Text):
        super().__init__()
        self.text = text

    def compose(self) -> ComposeResult:
        with VerticalScroll(id="conditions-dialog"):
            yield Static(self.text)


def conditions_text(model) -> Text:
    """The conditions as a reader wants them: name and verdict, then what it means and why it fails."""
    text = Text("Safety conditions over the trace so far  (c or Escape: close)\n", style="bold")
    for name, verdict, level, description in model.conditions():
        text.append(f"\n{name}  ", style="bold")
        text.append(verdict, style=STYLE.get(level, ""))
        if description:
            text.append(f"\n    {description}", style="italic")
        why = model.explanations.get(name)
        if why and verdict.startswith("violated"):
            text.append(f"\n    why: {why}", style=STYLE.get("ERROR", ""))
    return text


class Dashboard(App):
    """The dashboard of one cell, fed by a ``LiveFeed`` or a ``ReplayFeed``."""

    TITLE = "cellsim dashboard"
    # The cell and its hazards come first and keep their rows on a small terminal (80 x 24);
    # the panels below share what is left, and the event log keeps a few lines.
    CSS = """
    Screen { overflow: hidden; }
    #header { height: 1; background: $boost; }
    #top { height: auto; max-height: 10; }
    #top > Panel { width: 1fr; }
    #entities { max-height: 9; }
    #middle { height: 1fr; min-height: 0; overflow: hidden; }
    #middle > Panel { width: 1fr; }
    RichLog { height: 6; border-top: solid $primary; }
    ChoiceScreen, ConfirmScreen, ConditionsScreen { align: center middle; }
    #conditions-dialog { width: 90%; height: 80%; border: thick $primary; background: $surface; padding: 0 1; }
    #dialog { width: 60; height: auto; max-height: 20; border: thick $primary; background: $surface; padding: 1; }
    """
    BINDINGS = [Binding("m", "switch_mode", "switch a twin mode"), Binding("c", "show_conditions", "conditions in full"),
                Binding("q", "quit", "quit")]

    def __init__(self, feed):
        super().__init__()
        self.feed = feed
        self._logged = 0
        self._shown: dict[str, object] = {}
        self.terminated = False
        """Whether SIGTERM ended it (the command then ends as Ctrl-C does: exit 130); set by the command's own
        handler for a SIGTERM that came before the screen was up, which then ends it as soon as it is."""
        self._before_term = None
        self._term_installed = False

    def _view(self, selector: str, kind):
        """A widget of the dashboard's own screen (the first on the stack, whatever choice is shown over it);
        IndexError once the app has taken its screens down, NoMatches before they are mounted."""
        return self.screen_stack[0].query_one(selector, kind)

    def _show(self, panel: str, rows, draw, width: int | None = None) -> None:
        """Redraw a panel only when what it shows (or the ``width`` it is drawn for) changed:
        a title, a header and a line per row."""
        if self._shown.get(panel) != (width, rows):
            self._shown[panel] = (width, rows)
            self._view(f"#{panel}", Panel).show(draw(rows), len(rows) + 2)

    def compose(self) -> ComposeResult:
        yield Panel(id="header")
        with Horizontal(id="top"):
            yield Panel(id="cell")
            yield Panel(id="hazards")
        yield Panel(id="entities")
        with Horizontal(id="middle"):
            yield Panel(id="conditions")
            yield Panel(id="robot")
            yield Panel(id="links")
        yield RichLog(id="events", max_lines=500, markup=False)
        yield Footer()

    def on_mount(self) -> None:
        self._end_on_sigterm()
        if self.terminated:  # SIGTERM came while it started
            self.exit()
            return
        self.refresh_views()
        self.set_interval(1.0 / REFRESH, self.refresh_views)

    def _end_on_sigterm(self) -> None:
        """SIGTERM ends the app from inside its own loop. A KeyboardInterrupt raised by a Python signal handler lands
        in whatever the loop runs at that moment, and Textual lost it while it started (a review saw ``kill`` leave
        the screen up in 2 of 4 tries): the loop's own handler asks the app to exit, as ``q`` does."""
        import asyncio
        import signal

        def terminated():
            self.terminated = True
            self.exit()

        try:
            before = signal.getsignal(signal.SIGTERM)
            asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, terminated)
            self._before_term, self._term_installed = before, True
        except (NotImplementedError, RuntimeError, ValueError):  # no such handlers here (not the main thread)
            pass

    def on_unmount(self) -> None:
        import asyncio
        import signal

        if self._term_installed:  # the handler the command had is back once the screen is down
            asyncio.get_running_loop().remove_signal_handler(signal.SIGTERM)
            signal.signal(signal.SIGTERM, self._before_term if self._before_term is not None else signal.SIG_DFL)
            self._term_installed = False

    def refresh_views(self) -> None:
        try:
            header, log = self._view("#header", Panel), self._view("#events", RichLog)
        except (NoMatches, IndexError):  # the views are not mounted yet, or being taken down: nothing to draw on
            return
        try:
            self.feed.drain()
        except Exception as e:  # noqa: BLE001 - the network or a message: shown, never fatal
            log.write(f"feed error: {e}")
        model = self.feed.model
        if model is None:
            cell = getattr(self.feed, "cell", None)
            header.show(Text(f"cellsim dashboard: no twin running{' of ' + cell if cell else ''}; waiting for one ...",
                             style="bold"), 1)
            return
        state = {"running": "twin running", "gone": "TWIN GONE", "waiting": "waiting for the twin",
                 "replay": f"replay of {self.feed.source}", "ended": f"replay of {self.feed.source} (ended)"}[model.twin]
        lag = (model.status or {}).get("lag")
        lag_text = f"  lag {lag * 1000:.1f} ms" if isinstance(lag, (int, float)) else ""
        reaction_text, slower = model.reaction_text()
        header.show(Text(f"t = {model.sim_time:7.2f} s  |  {model.name}  |  {state}{lag_text}{reaction_text}",
                         style="bold red" if model.twin == "gone" or slower else "bold"), 1)
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
        self._show("cell", model.cell_rows(), lambda rows: _grid("cell", ("", ""), rows))

    def _hazards(self, model) -> None:
        rows = [(n, (p, STYLE[lv]), f"{s:.0f} s", _level(lv)) for n, p, s, lv in model.hazard_rows()]
        self._show("hazards", rows, lambda rows: _grid("hazards", ("hazard", "phase", "for", ""), rows))

    def _entities(self, model) -> None:
        rows = []
        for r in model.entity_rows():
            style = "bold yellow" if r["diverges"] else ""
            rows.append((r["entity"], r["mode"], _level(r["level"]), "-" if r["age"] is None else f"{r['age'] * 1000:.0f} ms",
                         (r["twin"], style), (r["physical"] + (" (differs)" if r["diverges"] else ""), style)))
        self._show("entities", rows, lambda rows: _grid("entities", ("entity", "mode", "link", "age", "twin", "physical"), rows))

    def _conditions(self, model) -> None:
        rows = [(name, (verdict, STYLE.get(level, "")), (description, "dim"))
                for name, verdict, level, description in model.conditions()]
        room = self._view("#conditions", Panel).size.width
        self._show("conditions", rows, lambda rows: _grid("safety conditions (so far)", ("condition", "verdict", "meaning"), rows, room),
                   width=room)

    def _robot_and_links(self, model) -> None:
        self._show("robot", model.robot_rows(), lambda rows: _grid("robot", ("", ""), rows))
        rows = []
        for device, status in sorted(model.diagnostics.items()):
            if device == "bridge":
                continue
            errors = sum(v for v in (status.get("counts") or {}).values() if isinstance(v, int))
            rate = status.get("rate_hz")
            rows.append((device, _level(model.diagnostics_level(device)), "-" if rate is None else f"{rate:.0f} Hz",
                         str(errors)))
        self._show("links", rows or [("(no bridge daemon)", "-", "", "")],
                   lambda rows: _grid("bridge diagnostics", ("device", "level", "rate", "errors"), rows))

    # -- interaction -----------------------------------------------------------------
    def action_show_conditions(self) -> None:
        model = self.feed.model
        if model is None:
            self.query_one("#events", RichLog).write("no conditions yet: no twin or replay to read")
            return
        self.push_screen(ConditionsScreen(conditions_text(model)))

    def action_switch_mode(self) -> None:
        model = self.feed.model
        if model is None or not hasattr(self.feed, "request_mode"):
            self.query_one("#events", RichLog).write("twin modes can be switched only on a running twin")
            return
        if not getattr(self.feed, "may_switch", True):
            self.query_one("#events", RichLog).write(
                "an observer may not switch twin modes: start the dashboard with --role engineer")
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
