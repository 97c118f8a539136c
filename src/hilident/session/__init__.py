"""One bench session, step by step: connect, arm, excite, record, identify, upload, verify, end.

May import everything but ``cli``.
"""
