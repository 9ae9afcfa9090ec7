"""Geometry of interfaces: polylines and their checks (:mod:`.interface`), closest
points and rays (:mod:`.projection`), interfaces segmented from OCT images
(:mod:`.imaging`), 3D observed surfaces and their plane sections (:mod:`.surface`), the
colony's surface from an OCT volume (:mod:`.volume`). Depends on nothing else of the package."""
