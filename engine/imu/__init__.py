"""IMU fusion (seed paper 002): orientation filters, import, jump sync, fused skeleton.

Modules:
    madgwick: Madgwick's gradient-descent filter (IMU/MARG), matching ``ahrs``.
    filter: gaitrig's orientation filter (rest/bias/disturbance handling; ENU output).
    io: x-IMU CSV, Madgwick .mat, BROAD .hdf5/.mat, generic CSV -> ``ImuRecording``.
    sync: five-jump synchronisation of IMU streams and the depth skeleton.
    fusion: plank calibration, bone mapping, fused skeleton, joint angles, RMSE/NCC.
    metrics: BROAD orientation error measure, RMSE, NCC.
    pipeline: end-to-end session processing and CSV export.
"""
