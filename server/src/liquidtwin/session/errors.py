"""The engine's one exception: a bad spec or request, with the wire error code to send."""

from __future__ import annotations

from liquidtwin_proto import liquidtwin_pb2 as pb

BAD_REQUEST = pb.Error.BAD_REQUEST
UNKNOWN_NAME = pb.Error.UNKNOWN_NAME
INFEASIBLE = pb.Error.INFEASIBLE


class EngineError(ValueError):
    """A session spec or request the engine cannot carry out.

    Attributes:
      code: ``liquidtwin_proto`` ``Error.Code`` value (BAD_REQUEST, UNKNOWN_NAME, INFEASIBLE, …)
        the service puts in its error reply; the message says what is wrong in the caller's terms.
    """

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = int(code)

    def __repr__(self) -> str:
        return f"EngineError({pb.Error.Code.Name(self.code)}, {str(self)!r})"
