"""``cellsim twin-mode``: switch an entity of the running twin to model, shadow or twin."""

from __future__ import annotations

import math
import sys

from cellsim.cli.common import EXIT_INPUT, EXIT_OK, InputError, _add_network_args, _network_security, _open_session


def add_parser(subparsers) -> None:
    mode = subparsers.add_parser(
        "twin-mode",
        help="switch an entity of the running twin to model, shadow or twin",
        description="Ask the running twin (cellsim live) to switch ENTITY to MODE. Prints the twin's "
        "answer; exits 0 if accepted, 2 if refused or if no twin answers.",
    )
    mode.add_argument("entity", help="an entity of the running twin, e.g. light_barrier")
    mode.add_argument("mode", help="model, shadow or twin")
    mode.add_argument("--cell", default=None, help="the cell's name (default: the only twin that answers)")
    _add_network_args(mode)
    mode.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the answer (default 5)")
    mode.set_defaults(handler=run)


def run(args) -> int:
    from cellsim import codec
    from cellsim.live import keys

    if not (math.isfinite(args.timeout) and 0.0 < args.timeout <= 3600.0):
        raise InputError(f"--timeout {args.timeout:g}: expected more than 0 and at most 3600 seconds")
    security = _network_security(args, "engineer")  # a keys problem is said as it is, not as an absent twin
    try:
        session = _open_session(args, "engineer", listen_by_default=False, wait=args.timeout, security=security)
    except InputError:
        why = "" if security["insecure"] else " (is the twin running, with --keys of the same CA as this engineer's?)"
        print(f"cellsim: error: no running twin reachable within {args.timeout:g} s{why}", file=sys.stderr)
        return EXIT_INPUT
    try:
        selector = keys.twin_mode_control(args.cell) if args.cell else f"{keys.ROOT}/*/control/twin_mode"
        request = codec.encode_mode_request(args.entity, args.mode, f"cellsim twin-mode ({session.zid()})")
        answers = []
        for reply in session.get(selector, payload=request, timeout=args.timeout):
            if reply.ok is not None:
                answers.append(codec.decode_answer(reply.ok.payload.to_bytes()))
    finally:
        session.close()
    if not answers:
        print(f"cellsim: error: no running twin answered on {selector} within {args.timeout:g} s", file=sys.stderr)
        return EXIT_INPUT
    answer = answers[0]
    print(("accepted: " if answer.get("accepted") else "refused: ") + str(answer.get("reason", "")))
    return EXIT_OK if answer.get("accepted") else EXIT_INPUT
