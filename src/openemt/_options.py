"""``option(default, help, **metadata)``: a field of a workflow's options dataclass whose
metadata carries its command-line help (read by ``openemt.cli._common.add_options``)."""

import dataclasses

__all__ = ["option"]


def option(default, help_: str, **metadata):
    """A dataclass field with ``default`` and metadata ``{"help": help_, **metadata}``."""
    return dataclasses.field(default=default, metadata={"help": help_, **metadata})
