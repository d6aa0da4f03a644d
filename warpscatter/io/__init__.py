"""Files in and out: images through OpenImageIO and the render's output set (:mod:`.images`), what made an output
(:mod:`.provenance`), image error metrics (:mod:`.metrics`) and the bundled configs and assets (:mod:`.resources`)."""
