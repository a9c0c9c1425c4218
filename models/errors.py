"""Exception hierarchy of the `models` package."""


class ModelError(Exception):
    """Base class of every error raised by `models`."""


class StrokeOutOfRangeError(ModelError, ValueError):
    """A cylinder stroke lies outside the range its closed chain admits."""

    def __init__(self, chain: str, stroke: float, lower: float, upper: float):
        self.chain = chain
        self.stroke = stroke
        self.lower = lower
        self.upper = upper
        super().__init__(
            f"stroke {stroke:.6g} m outside [{lower:.6g}, {upper:.6g}] m for cylinder chain "
            f"'{chain}'"
        )


class JointOutOfRangeError(ModelError, ValueError):
    """A joint angle lies outside the range its closed chain can reach."""

    def __init__(self, chain: str, angle: float, lower: float, upper: float):
        self.chain = chain
        self.angle = angle
        super().__init__(
            f"joint angle {angle:.6g} rad outside [{lower:.6g}, {upper:.6g}] rad for chain "
            f"'{chain}'"
        )


class StateError(ModelError, ValueError):
    """A machine state has a wrong shape or a non-finite entry."""


class TerrainError(ModelError, ValueError):
    """A terrain was given invalid parameters, or queried outside its extent."""


class PlacementError(ModelError, RuntimeError):
    """The machine could not be placed on the terrain at the requested pose."""
