"""Files: run records (:mod:`.runrecord`), the observation store
(:mod:`.observation_store`), observation files read into interfaces
(:mod:`.observations`) and the one atomic writer (:mod:`._atomic_write`)."""
