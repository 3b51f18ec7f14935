"""A crew of threads that share a batch's rows in chunks claimed under a lock (the same bits on any number).

The caller works too and waits only for chunks already claimed (a helper woken late claims nothing); helpers
start at the first batch and sleep between; a thread working beside (the auction) takes a hand (`working_beside`).
"""

cdef struct Crew:
    pthread_mutex_t lock
    pthread_cond_t wake  # a batch is posted
    pthread_cond_t done  # the last claimed chunk of a batch is worked
    int started  # helper threads running (hands 1..started)
    unsigned long posted  # batches posted so far: a helper sleeps until this moves
    bint busy  # a batch is being shared (one at a time; another caller works its rows alone)
    RowsJob run
    void *job
    int hands  # hands that may claim this batch's rows (a hand's scratch exists below this)
    Py_ssize_t next, rows, chunk  # the next unclaimed row, the batch's rows, rows per claim
    int working  # chunks claimed and not yet done
    int beside  # other threads of the process at work on a core (working_beside)


cdef Crew crew
pthread_mutex_init(&crew.lock, NULL)
pthread_cond_init(&crew.wake, NULL)
pthread_cond_init(&crew.done, NULL)


cdef void _work(int hand) noexcept nogil:
    """Claim and work chunks of the posted batch until none is left (called and returns with the lock held)."""
    cdef Py_ssize_t start, stop
    cdef RowsJob run
    cdef void *job
    while hand < crew.hands and crew.next < crew.rows:
        start, run, job = crew.next, crew.run, crew.job
        stop = min(start + crew.chunk, crew.rows)
        crew.next = stop
        crew.working += 1
        pthread_mutex_unlock(&crew.lock)
        run(job, hand, start, stop)
        pthread_mutex_lock(&crew.lock)
        crew.working -= 1
        if crew.working == 0:
            pthread_cond_signal(&crew.done)


cdef void *_helper(void *arg) noexcept nogil:
    cdef int hand = <int><size_t>arg
    cdef unsigned long seen = 0
    pthread_mutex_lock(&crew.lock)
    while True:
        while crew.posted == seen:
            pthread_cond_wait(&crew.wake, &crew.lock)
        seen = crew.posted
        _work(hand)
    return NULL


cdef int most_hands(Py_ssize_t rows, Py_ssize_t chunk, int hands) noexcept nogil:
    """The most hands share_rows may give a batch: the caller makes each one's scratch."""
    return max(1, min(hands, MAX_HANDS, (rows + chunk - 1) // chunk))


cdef void share_rows(RowsJob run, void *job, Py_ssize_t rows, Py_ssize_t chunk, int hands) noexcept nogil:
    """run(job, hand, start, stop) over rows 0..rows - 1 in chunks of ``chunk``, shared among up to
    ``hands`` threads (this one included); returns when every row is done."""
    cdef pthread_t thread
    pthread_mutex_lock(&crew.lock)
    hands = most_hands(rows, chunk, hands - crew.beside)
    if hands == 1 or crew.busy:
        pthread_mutex_unlock(&crew.lock)
        run(job, 0, 0, rows)
        return
    while crew.started < hands - 1:
        if pthread_create(&thread, NULL, _helper, <void*><size_t>(crew.started + 1)) != 0:
            break  # fewer hands: the rows are shared among those there are
        pthread_detach(thread)
        crew.started += 1
    crew.busy, crew.run, crew.job, crew.hands = True, run, job, hands
    crew.next, crew.rows, crew.chunk = 0, rows, chunk
    crew.posted += 1
    pthread_cond_broadcast(&crew.wake)
    _work(0)
    while crew.working:
        pthread_cond_wait(&crew.done, &crew.lock)
    crew.busy, crew.rows, crew.job = False, 0, NULL  # a helper that wakes late finds nothing to claim
    pthread_mutex_unlock(&crew.lock)


cdef void working_beside(int threads) noexcept nogil:
    """``threads`` more (or, negative, fewer) threads of this process now work beside the crew."""
    pthread_mutex_lock(&crew.lock)
    crew.beside += threads
    pthread_mutex_unlock(&crew.lock)
