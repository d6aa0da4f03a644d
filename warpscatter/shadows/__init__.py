"""Shadow techniques: shadow maps, PCF, moment shadow maps (Peters et al. 2017) and their building blocks.

``from warpscatter.shadows import moments`` gives the moment math (``@wp.func`` building blocks that user kernels
may call, and thin numpy host wrappers); :mod:`.settings` holds the Warp-free settings models. Importing this
package itself imports nothing (so the settings load without Warp).
"""
