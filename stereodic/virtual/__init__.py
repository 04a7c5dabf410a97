"""One camera's rays -> a virtual camera: the optical centre or telecentric fit and the virtual sensor
(`camera`), the Inverse Mapping Matrix (`imm`) and its bilinear sampler (`sampling`), the virtual PRVM
and Error Vector Matrix (`prvm`), undistortion (`undistort`), the pinhole export of one camera
(`export`) and pictures (`plots`)."""
