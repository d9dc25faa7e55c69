"""The benchmarks (`make bench`): the core against Pinocchio and MuJoCo (core), the control loop's
rate and real-time figures (loop), the view (view), the validator and TOPP-RA (validate), the CAN
transports (can) and the firmware's cycle budget under QEMU (fw_budget). Each prints its table as
ratios against a reference measured in the same run; none is a test."""
