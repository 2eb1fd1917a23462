"""MaterialX reading a document brdffit wrote, the way tests/test_export_materialx.py, tests/test_openpbr.py and
scripts/renderer_gallery.py check it: parsed by the `materialx` package (the test extra) with MaterialX's standard
data libraries imported, which validation and shader generation need."""


def load(text: str):
    """The MaterialX document of ``text`` with the standard libraries imported (`MaterialX` must be installed)."""
    import MaterialX as mx

    doc = mx.createDocument()
    mx.readFromXmlString(doc, text)
    libraries = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), libraries)
    doc.importLibrary(libraries)
    return doc
