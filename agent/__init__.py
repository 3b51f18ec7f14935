# OpenBLAS with one thread unless the user set otherwise (os.environ.setdefault): an entry point sets it
# before numpy loads, and the processes it starts inherit it. Our processes keep their cores busy with
# threads of their own: OpenBLAS's thread per core would only spin beside them.
ONE_BLAS_THREAD = ("OPENBLAS_NUM_THREADS", "1")
