"""Rendering of the glove hand and building of posture databases (may use pyrender)."""
