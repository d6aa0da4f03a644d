"""Many renders: executors (:mod:`.jobs`), animations (:mod:`.animation`), parameter sweeps (:mod:`.sweep`) and the
docs' gallery (:mod:`.gallery`)."""
