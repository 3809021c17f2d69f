"""Shared vocabulary of the glove tracker: hand model, glove pattern, database format, search.

Importing this package never opens an OpenGL context and never imports ``builder``.
"""

__version__ = "0.1.0"
