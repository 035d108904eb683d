"""The ``clradcom`` command: ``clradcom devices`` lists the OpenCL devices it sees."""

from __future__ import annotations

import argparse
import sys

from clradcom.device.runtime import ENV_DEVICE, OpenCLError, choose_device, list_devices


def _cmd_devices(args) -> int:
    infos = list_devices()
    chosen = choose_device(args.device)
    print("OpenCL devices (select with --device P:D, 'gpu', 'cpu', a name fragment,")
    print(f"or the environment variable {ENV_DEVICE}):")
    for info in infos:
        mark = "*" if info == chosen else " "
        print(f" {mark} {info.describe()}")
    print(f"default: [{chosen.spec}] {chosen.device_name.strip()}")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="clradcom",
        description="OpenCL radio ray tracer with an OFDM RadCom radar back end.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p_dev = sub.add_parser("devices", help="list the OpenCL devices and the one chosen")
    p_dev.add_argument("--device", default=None, help="device spec to test the choice of")
    p_dev.set_defaults(func=_cmd_devices)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except OpenCLError as exc:
        print(f"clradcom: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
