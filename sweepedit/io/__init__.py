"""Input and output: shape loading and normalisation, voxelisation, samples, parameter files."""
