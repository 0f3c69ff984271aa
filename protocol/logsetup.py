"""The services' shared ``--log-level`` option: its default comes from ``$IEA_LOG_LEVEL`` (else INFO)."""

from __future__ import annotations

import argparse
import logging
import os

LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
LOG_FORMAT = "%(asctime)s %(name)s %(levelname)s %(message)s"


def add_log_level_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--log-level", default=os.environ.get("IEA_LOG_LEVEL", "INFO").upper(), choices=LOG_LEVELS,
                        help="log level (default: $IEA_LOG_LEVEL, else INFO)")


def configure_logging(parser: argparse.ArgumentParser, args: argparse.Namespace, **basic_config) -> None:
    """``logging.basicConfig`` at ``args.log_level``; a bad ``$IEA_LOG_LEVEL`` (argparse does not check
    defaults against ``choices``) fails through ``parser.error``, naming it."""
    if args.log_level not in LOG_LEVELS:
        parser.error(f"IEA_LOG_LEVEL={args.log_level!r} is not one of {', '.join(LOG_LEVELS)}")
    logging.basicConfig(level=args.log_level, format=LOG_FORMAT, **basic_config)
