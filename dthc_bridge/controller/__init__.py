"""The plasma controller: typed commands, G-code dialect parsing, the cut sequence."""

__all__: list[str] = []
