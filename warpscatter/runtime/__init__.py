"""What every layer may use while it runs: Warp's set-up and the render's device (:mod:`.device`), CPU launches split
across cores (:mod:`.parallel`), fast transcendental approximations (:mod:`.fastmath`), reuse of freed buffers
(:mod:`.heap`), and named, timed stages with progress (:mod:`.stages`)."""
