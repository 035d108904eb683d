"""The OpenCL device: runtime (device choice, kernel builds), the ray caster that alone
drives the kernels, and visibility (segment confirmation) for every mechanism."""
