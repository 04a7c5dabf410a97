"""The workspace's web server: the Dash application (`app.make_app`) on a threaded WSGI server, with the
access rules of `access` on every request, the images it shows, and plain one-line errors.

Routes besides Dash's own: `/image?path=P` (an image under the served folders, or a frame `FILE::K` of a
video there, as an 8-bit PNG: 16-bit images scaled between their 0.5th and 99.5th percentiles, colour as
grey). Every request passes
`Access.allows` first (403 and one line without the token); a bad parameter answers 400 with one line, and
an internal error 500 with one line, never a traceback page.
"""

from __future__ import annotations

import threading
import webbrowser
from pathlib import Path

import numpy as np

from calib.errors import InputError
from calib.sequences import parse_frame_ref
from stereodic.workspace.access import COOKIE, Access


def _png(path: Path) -> bytes:
    """The image at `path` as 8-bit grey PNG bytes (module docstring)."""
    import cv2

    from calib.imageio import read_gray
    img = read_gray(path)
    if img.dtype != np.uint8:
        lo, hi = np.percentile(img, [0.5, 99.5])
        img = np.clip((img.astype(np.float64) - lo) * (255.0 / max(hi - lo, 1.0)), 0, 255).astype(np.uint8)
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return buf.tobytes()


def install_rules(server, access: Access) -> None:
    """The token check, the image route and the error pages on the Flask `server` (module docstring)."""
    from flask import Response, request

    def plain(text: str, status: int) -> Response:
        return Response(text + "\n", status=status, mimetype="text/plain")

    @server.before_request
    def _token():
        if not access.allows(request.args.get("token") or request.cookies.get(COOKIE)):
            return plain("stereodic view: this workspace needs its token: open the address it printed "
                         "(...?token=...)", 403)

    @server.after_request
    def _remember(response):
        token = request.args.get("token")
        if access.token is not None and access.allows(token):
            response.set_cookie(COOKIE, token, httponly=True, samesite="Strict")
        response.headers["X-Content-Type-Options"] = "nosniff"
        return response

    @server.route("/image")
    def _image():
        name = request.args.get("path", "")
        if not name:
            return plain("stereodic view: /image needs ?path=IMAGE", 400)
        try:
            path = access.resolve(name)
            if not (path.is_file() or parse_frame_ref(path)):    # an image file, or a video's frame FILE::K
                return plain(f"stereodic view: {name}: no such image", 404)
            data = _png(path)
        except InputError as exc:
            return plain(f"stereodic view: {exc}", 403 if "outside" in exc.problem else 400)
        return Response(data, mimetype="image/png", headers={"Cache-Control": "private, max-age=3600"})

    @server.errorhandler(404)
    def _missing(_):
        return plain(f"stereodic view: {request.path}: no such page", 404)

    @server.errorhandler(Exception)
    def _internal(exc):
        from werkzeug.exceptions import HTTPException
        if isinstance(exc, HTTPException):
            return plain(f"stereodic view: {exc.name}: {exc.description}", exc.code)
        return plain(f"stereodic view: internal error ({type(exc).__name__}: {exc})", 500)


class Workspace:
    """The running server: `url` (with the token); `serve()` answers requests until `stop()` (from another
    thread) or Ctrl-C; made by `start`."""

    def __init__(self, httpd, url: str):
        self._httpd = httpd
        self.url = url
        self._thread: threading.Thread | None = None

    def serve(self) -> None:
        self._httpd.serve_forever()

    def stop(self) -> None:
        if self._thread is not None:
            self._httpd.shutdown()
        self._httpd.server_close()


def start(paths: list[Path], *, host: str = "127.0.0.1", port: int = 0, token: str | None = None,
          background: bool = False) -> Workspace:
    """Serve the workspace on `paths` (the first is opened; all are served).

    Parameters
    ----------
    paths : list of Path
        What to look at and serve (module docstring of `app`); checked to exist by the caller.
    host : str
        Address to bind; not loopback only with a token (`access.check_host`).
    port : int
        TCP port; 0: a free one.
    token : str or None
        Every request must carry it (None: none needed, loopback only).
    background : bool
        Serve from a thread and return at once (tests, the bench); else the caller runs `serve_forever`.

    Returns
    -------
    workspace : Workspace
        Its address (http://host:port/?token=...) and a way to stop it.
    """
    import logging

    from werkzeug.serving import make_server

    from stereodic.workspace.access import check_host
    from stereodic.workspace.app import make_app
    check_host(host, token)
    access = Access(list(paths), token)
    app = make_app(access)
    install_rules(app.server, access)
    logging.getLogger("werkzeug").setLevel(logging.ERROR)   # no line per request on the terminal
    try:
        httpd = make_server(host, port, app.server, threaded=True)
    except OSError as exc:
        raise InputError("--port", f"cannot listen on {host}:{port} ({exc.strerror})") from None
    shown = "127.0.0.1" if host in ("0.0.0.0", "::") else host
    url = f"http://{shown if ':' not in shown else f'[{shown}]'}:{httpd.server_port}/"
    if token is not None:
        url += f"?token={token}"
    ws = Workspace(httpd, url)
    if background:
        ws._thread = threading.Thread(target=ws.serve, name="stereodic-view", daemon=True)
        ws._thread.start()
    return ws


def open_browser(url: str) -> bool:
    """Open `url` in the user's browser where there is one; False where there is none (a head node)."""
    try:
        return webbrowser.get().open(url)
    except webbrowser.Error:
        return False
