"""skincal.hw"""
