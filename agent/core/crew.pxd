# POSIX threads, and a crew of them sharing a batch's rows (crew.pyx)

cdef extern from "<pthread.h>" nogil:
    ctypedef struct pthread_t:
        pass
    ctypedef struct pthread_mutex_t:
        pass
    ctypedef struct pthread_cond_t:
        pass
    int pthread_create(pthread_t* thread, void* attr, void* (*start)(void*) noexcept nogil, void* arg)
    int pthread_join(pthread_t thread, void** result)
    int pthread_detach(pthread_t thread)
    int pthread_mutex_init(pthread_mutex_t* mutex, void* attr)
    int pthread_mutex_destroy(pthread_mutex_t* mutex)
    int pthread_mutex_lock(pthread_mutex_t* mutex)
    int pthread_mutex_unlock(pthread_mutex_t* mutex)
    int pthread_cond_init(pthread_cond_t* cond, void* attr)
    int pthread_cond_destroy(pthread_cond_t* cond)
    int pthread_cond_wait(pthread_cond_t* cond, pthread_mutex_t* mutex)
    int pthread_cond_signal(pthread_cond_t* cond)
    int pthread_cond_broadcast(pthread_cond_t* cond)

cdef enum:
    MAX_HANDS = 16  # threads a batch is shared among, the caller's included

# rows start..stop - 1 of a job, by hand ``hand`` (0: the caller; each hand has its own scratch)
ctypedef void (*RowsJob)(void *job, int hand, Py_ssize_t start, Py_ssize_t stop) noexcept nogil

cdef int most_hands(Py_ssize_t rows, Py_ssize_t chunk, int hands) noexcept nogil
cdef void share_rows(RowsJob run, void *job, Py_ssize_t rows, Py_ssize_t chunk, int hands) noexcept nogil
cdef void working_beside(int threads) noexcept nogil
