"""Shape analysis: the medial-axis skeleton, quality metrics and off-screen renders."""
