"""Logging set-up: one pipeline for structlog and stdlib logging, JSON or console on stderr.

structlog events go through stdlib logging (``structlog.stdlib.LoggerFactory``), so the
name given to ``structlog.get_logger("dthc_bridge.link")`` is the stdlib logger's name. One
handler on the root logger renders every record with a ``ProcessorFormatter``: structlog's
events and foreign records (asyncio, the MQTT client) get the same fields - ``timestamp``
(ISO, UTC), ``level``, ``logger``, ``event`` - and the same renderer. Under JSON an
exception is a structured traceback (``dict_tracebacks``, without locals); on a terminal
the console renderer prints it.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

import structlog
from structlog.typing import Processor

from .link import frametrace

__all__ = ["configure_logging", "logging_configured"]

# Fields every line carries, whether the event came from structlog or from stdlib logging.
_SHARED_PROCESSORS: tuple[Processor, ...] = (
    structlog.stdlib.add_log_level,
    structlog.stdlib.add_logger_name,
    structlog.processors.TimeStamper(fmt="iso", utc=True),
)


class _PipelineHandler(logging.StreamHandler[TextIO]):
    """The root handler configure_logging installs; found and replaced on reconfiguration."""


def configure_logging(
    level: str = "info", *, json: bool | None = None, trace_frames: bool = False
) -> None:
    """Render structlog and stdlib logging to stderr; JSON when stderr is not a TTY.

    ``level`` filters structlog calls before any processing and stdlib records at the root
    logger. ``trace_frames`` makes each new board session keep its last frames and log them
    when a corrupt frame arrives. Calling this again replaces the previous set-up.
    """
    numeric_level = logging.getLevelNamesMapping()[level.upper()]
    stream = sys.stderr
    as_json = not stream.isatty() if json is None else json
    # Tracebacks without locals: a frame's locals can hold secrets and make lines huge.
    renderer: list[Processor] = (
        [
            structlog.processors.ExceptionRenderer(
                structlog.tracebacks.ExceptionDictTransformer(show_locals=False)
            ),
            structlog.processors.JSONRenderer(),
        ]
        if as_json
        else [
            structlog.dev.ConsoleRenderer(
                colors=stream.isatty(), exception_formatter=structlog.dev.plain_traceback
            )
        ]
    )
    handler = _PipelineHandler(stream)
    handler.setFormatter(
        structlog.stdlib.ProcessorFormatter(
            processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta, *renderer],
            foreign_pre_chain=_SHARED_PROCESSORS,
        )
    )
    root = logging.getLogger()
    for old in [h for h in root.handlers if isinstance(h, _PipelineHandler)]:
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(numeric_level)

    structlog.configure(
        processors=[
            *_SHARED_PROCESSORS,
            structlog.stdlib.ProcessorFormatter.wrap_for_formatter,
        ],
        # Drops calls below the level before any processor runs (the hot path's debug).
        wrapper_class=structlog.make_filtering_bound_logger(numeric_level),
        logger_factory=structlog.stdlib.LoggerFactory(),
        cache_logger_on_first_use=False,
    )
    frametrace.enable(frametrace.DEFAULT_CAPACITY if trace_frames else 0)


def logging_configured() -> bool:
    """Whether :func:`configure_logging` has set up the pipeline in this process."""
    return any(isinstance(h, _PipelineHandler) for h in logging.getLogger().handlers)
