"""``cellsim keys``: the cell's CA and a certificate per role, for mutual TLS on Zenoh (docs/security.md)."""

from __future__ import annotations

from pathlib import Path

from cellsim.cli.common import EXIT_OK, InputError


def add_parser(subparsers) -> None:
    from cellsim.live.pki import DEFAULT_DAYS, ROLES

    keys = subparsers.add_parser(
        "keys",
        help="create the cell's CA and one certificate per role, for mutual TLS between the twin and the cell",
        description="The live twin, the emulator, the bridge daemon, twin-mode and the dashboard all use TLS with "
        "mutual authentication: each shows a certificate of the cell's CA whose common name is its role ("
        f"{', '.join(ROLES)}), and the twin grants each role only what it needs. `keys init DIR` creates them; "
        "copy to each machine ca.pem and its role's .pem and .key, never ca.key. Without --keys, the commands "
        "use $CELLSIM_KEYS, else ~/.config/cellsim/keys, and create it on first use.",
    )
    actions = keys.add_subparsers(dest="action", metavar="ACTION", required=True)
    init = actions.add_parser("init", help="create a CA and every role's certificate and key in a new folder",
                              description="Create DIR/ca.pem and ca.key (the CA), and DIR/<role>.pem and <role>.key "
                              "for every role. DIR must be new or empty: keys are never overwritten; to rotate them, "
                              "create a new folder and restart every process with it (docs/security.md).")
    init.add_argument("folder", type=Path, metavar="DIR", help="the new folder for the keys (must not hold any)")
    init.add_argument("--host", action="append", default=[], metavar="NAME",
                      help="a host name or address the twin is reached by, besides localhost, 127.0.0.1 and ::1 "
                      "(repeatable); clients check it against the endpoint they connect to")
    init.add_argument("--days", type=int, default=DEFAULT_DAYS,
                      help=f"how long the certificates are valid (default {DEFAULT_DAYS})")
    show = actions.add_parser("show", help="list a folder's certificates: role, common name, expiry")
    show.add_argument("folder", type=Path, metavar="DIR", help="a folder written by keys init")
    keys.set_defaults(handler=run)


def run(args) -> int:
    from cellsim.live.pki import KeysError, describe, init_keys

    try:
        if args.action == "init":
            files = init_keys(args.folder, tuple(args.host), args.days)
            print(f"created {len(files)} files in {args.folder}: give each machine ca.pem and its role's "
                  ".pem and .key; keep ca.key offline")
        else:
            if not args.folder.is_dir():
                raise KeysError(f"{args.folder}: no such folder")
            print("\n".join(describe(args.folder)))
    except KeysError as e:
        raise InputError(str(e)) from None
    return EXIT_OK
