"""The model-file contract's constants: what an exported ONNX file's ``metadata_props`` are called.

Imports nothing (the torch-free predict path and the torch exporter both read it), so the schema
version a file is written with and the version a reader accepts are one number.
"""

#: the version written into ``metadata_props["hupbench.onnx_schema"]`` and the one readers accept
ONNX_SCHEMA = "1"
#: prefix of every hupbench metadata key
META = "hupbench."
