"""A crew of threads that share a batch's rows in chunks claimed under a lock (the same bits on any number).

The caller works too and waits only for chunks already claimed (a helper woken late claims nothing); helpers
start at the first batch and sleep between; a thread working beside (the auction) takes a hand (`working_beside`),
and works the rows left of the batch under way as that hand when it ends (it is awake; a helper would have to wake).
"""

cdef struct Crew:
    pthread_mutex_t lock
    pthread_cond_t wake  # a batch is posted
    pthread_cond_t done  # the last claimed chunk of a batch is worked
    int started  # helper threads running (hands 1..started)
    bint busy  # a batch is being shared (one at a time; another caller works its rows alone)
    RowsJob run
    void *job
    int hands  # hands that may claim this batch's rows (a hand's scratch exists below this)
    Py_ssize_t next, rows, chunk  # the next unclaimed row, the batch's rows, rows per claim
    int working  # chunks claimed and not yet done
    unsigned int at_work  # bit h: hand h works a chunk
    int beside  # other threads of the process at work on a core (working_beside)


cdef Crew crew
pthread_mutex_init(&crew.lock, NULL)
pthread_cond_init(&crew.wake, NULL)
pthread_cond_init(&crew.done, NULL)


cdef inline bint _may_claim(int hand) noexcept nogil:
    """Rows are left and ``hand`` may claim them: the caller always, a helper while the threads beside leave it a
    core (the hands from crew.hands - crew.beside up are theirs)."""
    return crew.next < crew.rows and (hand == 0 or hand < crew.hands - crew.beside)


cdef void _work(int hand, bint beside=False) noexcept nogil:
    """Claim and work chunks of the posted batch until none is left (called and returns with the lock held);
    ``beside``: a thread beside, as the first of their hands."""
    cdef Py_ssize_t start, stop
    cdef RowsJob run
    cdef void *job
    while beside and crew.next < crew.rows or _may_claim(hand):
        start, run, job = crew.next, crew.run, crew.job
        stop = min(start + crew.chunk, crew.rows)
        crew.next = stop
        crew.working += 1
        crew.at_work |= 1u << hand
        pthread_mutex_unlock(&crew.lock)
        run(job, hand, start, stop)
        pthread_mutex_lock(&crew.lock)
        crew.working -= 1
        crew.at_work &= ~(1u << hand)
        if crew.working == 0:
            pthread_cond_signal(&crew.done)


cdef void *_helper(void *arg) noexcept nogil:
    cdef int hand = <int><size_t>arg
    pthread_mutex_lock(&crew.lock)
    while True:
        while not _may_claim(hand):
            pthread_cond_wait(&crew.wake, &crew.lock)
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
    hands = most_hands(rows, chunk, hands)
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
    if hands > crew.beside + 1:
        pthread_cond_broadcast(&crew.wake)
    _work(0)
    while crew.working:
        pthread_cond_wait(&crew.done, &crew.lock)
    crew.busy, crew.rows, crew.job = False, 0, NULL  # a helper that wakes late finds nothing to claim
    pthread_mutex_unlock(&crew.lock)


cdef void working_beside(int threads) noexcept nogil:
    """``threads`` more (or, negative, fewer) threads of this process now work beside the crew; one that ends
    works the rows left of the batch under way first."""
    pthread_mutex_lock(&crew.lock)
    cdef int hand = crew.hands - crew.beside  # the first hand of those beside (a helper's chunk claimed before: not)
    if threads < 0 and crew.busy and 0 < hand < crew.hands and not crew.at_work & (1u << hand):
        _work(hand, True)
    crew.beside += threads
    pthread_mutex_unlock(&crew.lock)
