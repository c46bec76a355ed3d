"""The neural sweeper's training, a job of its own beside the per-shape fit (it uses
fitting's sweepers and parameter layout; nothing in fitting uses it).

train.py     training of the neural sweeper on random sweeps labelled by the exact test
             (`sweepedit train-sweeper`, or python -m sweepedit.training.train)
evaluate.py  its accuracy against the exact inside test, and speed, beside the analytic
             sweeper's (python -m sweepedit.training.evaluate)
"""
