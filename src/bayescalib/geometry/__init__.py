"""Geometry of interfaces: polylines and their checks (:mod:`.interface`), closest
points and rays (:mod:`.projection`), interfaces segmented from OCT images
(:mod:`.imaging`). Depends on nothing else of the package."""
