"""quadmanip.common"""
