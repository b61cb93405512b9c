"""skincal.calib"""
