"""The live viewer: ``foveawarp view`` serves a page whose canvas shows foveated frames that follow the mouse
(the gaze). The server needs the optional extra ``viewer`` (``pip install -e .[viewer]``); the message rules
(``protocol``) and the session (``session``) do not.

Use from Python::

    from foveawarp.viewer import ViewerSession, ViewerServer
    server = ViewerServer(ViewerSession(["cornell"], 320, 180, device="cpu"), port=0).start_in_thread()
    print(server.url)
    ...
    server.stop()
"""

from .protocol import KNOBS, ProtocolError, parse_message
from .session import ViewerSession

__all__ = ["KNOBS", "ProtocolError", "ViewerServer", "ViewerSession", "parse_message"]


def __getattr__(name):
    if name == "ViewerServer":
        from .server import ViewerServer

        return ViewerServer
    raise AttributeError(name)
