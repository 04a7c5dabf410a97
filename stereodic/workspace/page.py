"""What every page of the workspace shares: the width of a field's plot, the address of the server's
`/image` route for a file, and the one line a callback shows for a bad request."""

from __future__ import annotations

from pathlib import Path

from calib.errors import InputError

GRAPH_WIDTH_PX = 900   # the field's plot width, screen pixels


def image_url(path: Path | None) -> str | None:
    """The address under which the server sends the image file `path` (its `/image` route); None for None."""
    from urllib.parse import quote
    return None if path is None else f"/image?path={quote(str(path))}"


def error_text(exc: Exception) -> str:
    """The one line a callback shows for a bad request (an InputError's own text; another error's type
    and text)."""
    return f"{exc}" if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
