"""Shadow techniques: shadow maps, PCF, moment shadow maps (Peters et al. 2017) and their building blocks.
Importing the package imports nothing, so :mod:`.settings` loads without Warp."""
