"""The device layer: kernel sources and defines, struct layouts, the scene on a device, and what runs
on it (trace, render, Whitted). Below it: rtlab.backends (compile, launch); beside it: rtlab.accel
(the host-built structures it uploads)."""
