"""Runtime tracking from RGB-D input. Must not import ``builder`` or pyrender."""
