"""Files: run records (:mod:`.runrecord`), the observation store
(:mod:`.observation_store`), the training table (:mod:`.training`), observation files
read into interfaces (:mod:`.observations`; 3D colony surfaces from STL/PLY/VTK files:
:mod:`.surfaces`), the header every HDF5 file carries
(:mod:`.header`: kind and layout version, checked by every reader) and the one atomic
writer (:mod:`._atomic_write`). The GP surrogate and the SMC particles keep their
layouts next to the objects they store (``GPSurrogate.save``/``load``,
:mod:`bayescalib.inference.posterior`), since this layer sits below the inference; they
use the same header and writer."""
