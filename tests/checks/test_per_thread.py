import pickle
import threading

from checks.per_thread import PerThread


def test_each_thread_gets_its_own_object_once():
    made = []
    per = PerThread(lambda: made.append(1) or object())
    here = per.get()
    assert per.get() is here and len(made) == 1
    other = []
    t = threading.Thread(target=lambda: other.append(per.get()))
    t.start()
    t.join()
    assert other[0] is not here and len(made) == 2


def test_a_pickled_copy_starts_empty():
    per = PerThread(dict)
    per.get()["buffer"] = 1
    copy = pickle.loads(pickle.dumps(per))
    assert copy.get() == {} and per.get() == {"buffer": 1}
