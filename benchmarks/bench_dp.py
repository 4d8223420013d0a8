import time, numpy as np, scipy.sparse
from firmtool.graph import solve_dp, success_probability
rng=np.random.default_rng(0); N=100_000; k=10
src=np.repeat(np.arange(N),k); E=src.size
# landing: each edge lands in one of 3 "nearby" nodes (ring graph towards the goal), plus failure
t=np.stack([ (src + rng.integers(-3,8,size=E))%N for _ in range(2)],1)
w=rng.dirichlet([5,5,0.2],size=E)
landing=scipy.sparse.csr_matrix((w[:,:2].ravel(),(np.repeat(np.arange(E),2),t.ravel())),shape=(E,N))
landing.sum_duplicates()
fail=w[:,2]; cost=rng.uniform(0.5,2,size=E)
for m in ("value","policy"):
    t0=time.time(); r=solve_dp(N,0,src,cost,landing,fail,100.0,method=m); t1=time.time(); p=success_probability(N,0,r.policy,landing); t2=time.time()
    print(m, r.status, r.iterations, r.residual, "dp %.2fs sp %.2fs"%(t1-t0,t2-t1), p[:3])
