"""The defaults of a video recording (:mod:`instrument.acquisition.video`), in a module that imports
nothing, so that ``diffuserlab capture video --help`` states them without loading numpy
or zarr."""

__all__ = ["DEFAULT_COMPRESSOR", "DEFAULT_SHARD_FRAMES", "MAX_FRAMES"]

#: Frames per shard file of a video run (64 frames of 1200 x 1600 uint16: 245 MB).
DEFAULT_SHARD_FRAMES = 16
#: Most frames one recording takes (its run store holds one slot per frame).
MAX_FRAMES = 10_000_000
#: Lossless frame compressor of a video run (see ``diffuserlab benchmark recording``).
DEFAULT_COMPRESSOR = "blosc-lz4"
