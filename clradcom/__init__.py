"""clradcom: an OpenCL radio ray tracer with an OFDM RadCom radar back end."""

__version__ = "0.1.0"
