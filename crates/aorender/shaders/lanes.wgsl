// The adapter runs invocations as the lanes of a CPU's SIMD registers (lavapipe): the
// traversal then takes the formulations that compile to fewer instructions there
// (fmax_cpu, msb24). Both give the same results wherever no plane distance is NaN.
override CPU_LANES: bool = false;
