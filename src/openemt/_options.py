"""What the workflows share: ``option(default, help, **metadata)``, a field of a workflow's
options dataclass whose metadata carries its command-line help (read by the command layer's
``add_options``), and :data:`SILENT`, the ``say`` of a workflow run without stage lines."""

import dataclasses

__all__ = ["SILENT", "option"]


def option(default, help_: str, **metadata):
    """A dataclass field with ``default`` and metadata ``{"help": help_, **metadata}``."""
    return dataclasses.field(default=default, metadata={"help": help_, **metadata})


class _Silent:
    """A ``say`` that says nothing: neither the stage lines it is called with nor the compile
    notice written to it as a stream."""

    def __call__(self, text: str) -> None:
        pass

    write = __call__

    def flush(self) -> None:
        pass


SILENT = _Silent()
