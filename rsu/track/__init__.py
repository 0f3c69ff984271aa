"""Multi-object tracking: SORT (``sort``; its Python-float frame step for small frames in ``sort_scalar``), its IoU
association (``assoc``) and the thesis's two tracking frameworks over it (``frameworks``)."""
