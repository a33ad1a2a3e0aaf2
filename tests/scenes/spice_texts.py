"""The text kernels the SPICE tests write beside their CKs: a spacecraft clock (SCLK, id -999,
ticks of 1/65536 s counted from ``{et0}`` TDB) and a frame kernel (FK) tying the camera frame
``SKYNAV_CAM`` (-999000) to that clock and to the spacecraft -999. ``SCLK.format(et0=...)``."""

SCLK = """KPL/SCLK
\\begindata
SCLK_KERNEL_ID           = ( @2027-01-01/00:00 )
SCLK_DATA_TYPE_999       = ( 1 )
SCLK01_TIME_SYSTEM_999   = ( 1 )
SCLK01_N_FIELDS_999      = ( 2 )
SCLK01_MODULI_999        = ( 4294967296 65536 )
SCLK01_OFFSETS_999       = ( 0 0 )
SCLK01_OUTPUT_DELIM_999  = ( 1 )
SCLK_PARTITION_START_999 = ( 0.0 )
SCLK_PARTITION_END_999   = ( 2.8147497671065E+14 )
SCLK01_COEFFICIENTS_999  = ( 0.0 {et0} 1.0 )
\\begintext
"""
FK = """KPL/FK
\\begindata
FRAME_SKYNAV_CAM         = -999000
FRAME_-999000_NAME       = 'SKYNAV_CAM'
FRAME_-999000_CLASS      = 3
FRAME_-999000_CLASS_ID   = -999000
FRAME_-999000_CENTER     = -999
CK_-999000_SCLK          = -999
CK_-999000_SPK           = -999
\\begintext
"""
