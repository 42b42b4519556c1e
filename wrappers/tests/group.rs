//! Group laws, representations and field layouts.

use equigym_envs::tasks::{make_task, TaskOptions, TASK_IDS};
use equigym_envs::{Env, EnvConfig};
use equigym_wrappers::{transform_state, Block, Error, Group, PlanarRotation, Representation, TaskSymmetry};

fn close(a: &PlanarRotation, b: &PlanarRotation) -> bool {
    (a.cos() - b.cos()).abs() < 1e-12 && (a.sin() - b.sin()).abs() < 1e-12
}

fn matmul(a: &[f64], b: &[f64], d: usize) -> Vec<f64> {
    let mut out = vec![0.0; d * d];
    for i in 0..d {
        for k in 0..d {
            for j in 0..d {
                out[i * d + j] += a[i * d + k] * b[k * d + j];
            }
        }
    }
    out
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

#[test]
fn cyclic_group_laws() {
    for n in [1, 2, 4, 8, 12] {
        let g = Group::cyclic(n).unwrap();
        let e = g.elements().unwrap();
        assert_eq!(e.len(), n);
        assert!(close(&e[0], &PlanarRotation::IDENTITY));
        for a in 0..n {
            // Closure and the index law: g^a g^b = g^(a+b mod n).
            for b in 0..n {
                assert!(close(&e[a].compose(&e[b]), &e[(a + b) % n]), "C{n}: {a} + {b}");
                for c in 0..n {
                    let left = e[a].compose(&e[b]).compose(&e[c]);
                    let right = e[a].compose(&e[b].compose(&e[c]));
                    assert!(close(&left, &right));
                }
            }
            assert!(close(&e[a].compose(&e[a].inverse()), &PlanarRotation::IDENTITY));
            assert!(g.contains(&e[a]));
        }
        // The generator has order n.
        let gen = g.generator().unwrap();
        let mut p = PlanarRotation::IDENTITY;
        for _ in 0..n {
            p = p.compose(&gen);
        }
        assert!(close(&p, &PlanarRotation::IDENTITY));
    }
    // Quarter turns are exact.
    let c8 = Group::cyclic(8).unwrap();
    assert_eq!(c8.element(2).unwrap().cos(), 0.0);
    assert_eq!(c8.element(4).unwrap().sin(), 0.0);
    assert!(!c8.contains(&PlanarRotation::new(0.1).unwrap()));
    assert!(Group::SO2.contains(&PlanarRotation::new(0.1).unwrap()));
}

#[test]
fn group_errors_are_typed() {
    assert!(matches!(Group::cyclic(0), Err(Error::InvalidGroup(_))));
    assert!(matches!(Group::cyclic(8).unwrap().element(8), Err(Error::InvalidGroup(_))));
    assert!(matches!(Group::SO2.elements(), Err(Error::InvalidGroup(_))));
    assert!(matches!(PlanarRotation::new(f64::NAN), Err(Error::InvalidGroup(_))));
    assert!("C8".parse::<Group>().unwrap() == Group::Cyclic { order: 8 });
    assert!("so(2)".parse::<Group>().unwrap() == Group::SO2);
    assert!("D4".parse::<Group>().is_err());
}

#[test]
fn regular_representation_is_a_homomorphism() {
    let g = Group::cyclic(8).unwrap();
    for a in 0..8 {
        for b in 0..8 {
            let ra = g.regular_representation(a).unwrap();
            let rb = g.regular_representation(b).unwrap();
            assert_eq!(matmul(&ra, &rb, 8), g.regular_representation((a + b) % 8).unwrap());
        }
    }
}

#[test]
fn representations_are_orthogonal_homomorphisms() {
    let c8 = Group::cyclic(8).unwrap();
    for task in TASK_IDS {
        let sym = TaskSymmetry::new(task, &TaskOptions::default(), c8, 4).unwrap();
        for rep in [&sym.observation, &sym.action, &sym.chunk] {
            let d = rep.dim();
            let mut identity = vec![0.0; d * d];
            for i in 0..d {
                identity[i * d + i] = 1.0;
            }
            for a in 0..8 {
                let ga = c8.element(a).unwrap();
                let m = rep.matrix(&ga);
                let mut mt = vec![0.0; d * d];
                for i in 0..d {
                    for j in 0..d {
                        mt[j * d + i] = m[i * d + j];
                    }
                }
                assert!(max_diff(&matmul(&m, &mt, d), &identity) < 1e-12, "{task}: not orthogonal");
                for b in 0..8 {
                    let gb = c8.element(b).unwrap();
                    let prod = matmul(&m, &rep.matrix(&gb), d);
                    assert!(max_diff(&prod, &rep.matrix(&ga.compose(&gb))) < 1e-12, "{task}: rho(ab) != rho(a) rho(b)");
                }
            }
            // Acting equals multiplying by the matrix.
            let g = PlanarRotation::new(0.7).unwrap();
            let x: Vec<f64> = (0..d).map(|i| libm::sin(i as f64 * 0.37)).collect();
            let mut y = x.clone();
            rep.act(&g, &mut y).unwrap();
            let m = rep.matrix(&g);
            let mx: Vec<f64> = (0..d).map(|i| (0..d).map(|j| m[i * d + j] * x[j]).sum()).collect();
            assert!(max_diff(&y, &mx) < 1e-12);
        }
    }
}

#[test]
fn layouts_are_consistent_and_match_the_paper() {
    // (rho0 copies, rho1 copies) of each observation, from the paper's appendix tables
    // (6D rotations counted as rho1^3).
    let expected = [("lift", (4, 9)), ("stack", (7, 14)), ("square", (14, 9))];
    for (task, mult) in expected {
        let t = make_task(task, &TaskOptions::default()).unwrap();
        let layout = t.observation_layout();
        let rep = Representation::from_layout(layout);
        assert_eq!(rep.multiplicities(), mult, "{task}");
        // Every index is covered by exactly one block.
        let mut seen = vec![0; rep.dim()];
        for b in rep.blocks() {
            match *b {
                Block::Trivial { index } => seen[index] += 1,
                Block::Rotating { x, y, .. } => {
                    seen[x] += 1;
                    seen[y] += 1;
                }
            }
        }
        assert!(seen.iter().all(|&c| c == 1), "{task}");
    }
    // Action and chunk: rho1 + rho0, rho1^3, rho0 per action; the latent has the chunk's layout.
    let sym = TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 4).unwrap();
    assert_eq!(sym.action.multiplicities(), (2, 4));
    assert_eq!(sym.chunk.multiplicities(), (8, 16));
    assert_eq!(sym.chunk_len(), 4);
    assert_eq!(sym.chunk_layout.fields()[3].name, "t1.position");
}

/// The declared layout is what the environment writes: rotating the scene by g (objects, hand,
/// fingers) must turn the observation by the representation built from the layout, for every
/// element and task. A field written in another order or frame than its declared kind breaks
/// this (the layout's own bookkeeping is `Layout::with`'s business, not this test's).
#[test]
fn observations_transform_as_their_declared_layout() {
    let group = Group::cyclic(8).unwrap();
    for task in TASK_IDS {
        let mut env = Env::new(EnvConfig::new(task)).unwrap();
        let rep = Representation::from_layout(env.observation_layout());
        for seed in [0, 1] {
            env.reset(seed).unwrap();
            let hold = env.current_target();
            env.step(&hold).unwrap();
            let state = env.get_state().unwrap();
            let obs = env.observe().to_vec();
            for k in 1..group.order().unwrap() {
                let g = group.element(k).unwrap();
                env.set_state(&state).unwrap();
                transform_state(&mut env, &g).unwrap();
                let mut want = obs.clone();
                rep.act(&g, &mut want).unwrap();
                let got = env.observe().to_vec();
                let err = max_diff(&got, &want);
                assert!(
                    err < 1e-5,
                    "{task}, seed {seed}, element {k}: observation off by {err}\n got {got:?}\nwant {want:?}"
                );
            }
        }
    }
}

#[test]
fn bad_inputs_give_errors_and_leave_data_alone() {
    let sym = TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 4).unwrap();
    let g = sym.group.element(1).unwrap();
    let mut short = vec![0.0; 9];
    assert!(matches!(sym.act_action(&g, &mut short), Err(Error::Env(equigym_envs::EnvError::WrongLength { .. }))));
    let mut nan = vec![0.1; 20];
    nan[13] = f64::NAN;
    let before = nan.clone();
    assert!(matches!(
        sym.act_action(&g, &mut nan),
        Err(Error::Env(equigym_envs::EnvError::NonFinite { index: 13, .. }))
    ));
    assert_eq!(nan[..13], before[..13]);
    let mut rows = vec![0.5; 20];
    assert!(sym.action.act_each(&[g], &mut rows).is_err());
    assert!(sym.action.act_each(&[g, g], &mut rows).is_ok());
    assert!(TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 0).is_err());
}
