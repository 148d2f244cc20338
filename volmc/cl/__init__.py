"""OpenCL host side: device choice, program build and cache, parameter structs, launches."""
