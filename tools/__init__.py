"""The firmware's build tools, apart from the ground tools people run: ``mpy_build`` (the firmware and the protocol
core as .mpy, ``make mpy``), ``natmod_build`` (the ADCS kernels as a native module, ``make natmod``) and
``pil_build`` (the processor-in-the-loop images under QEMU, ``make pil``)."""
