"""The ManiSkill observation cameras' lean scene (mimicgen_pipe/backends/maniskill/render.py):
its mesh changes keep a mesh's shape and a ground's texture mapping, and a stored state's
pictures through it are still the scene: the cubes, the arm, the hand and the table where
the full renderer shows them, the colours of its picture close to the full one's."""

from __future__ import annotations

import numpy as np
import pytest

from mimicgen_pipe.backends.maniskill.render import cluster_mesh, flat_quad

CAMERAS = ("agentview", "eye_in_hand")


def sphere(n: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An unindexed unit sphere of 2 n^2 triangles, as SAPIEN holds the Panda's meshes:
    (vertices, triangles, normals), counter-clockwise seen from outside."""
    theta, phi = np.linspace(0, np.pi, n + 1), np.linspace(0, 2 * np.pi, n + 1)
    p = np.stack(np.meshgrid(theta, phi, indexing="ij"), -1)
    grid = np.stack([np.sin(p[..., 0]) * np.cos(p[..., 1]),
                     np.sin(p[..., 0]) * np.sin(p[..., 1]), np.cos(p[..., 0])], -1)  # fmt: skip
    a, b, c, d = grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], 2), np.stack([a, c, d], 2)]).reshape(-1, 3, 3)
    v = tris.reshape(-1, 3)
    return v, np.arange(len(v)).reshape(-1, 3), v / np.linalg.norm(v, axis=1, keepdims=True)


def signed_volume(v: np.ndarray, t: np.ndarray) -> float:
    return float(np.einsum("ij,ij->i", v[t[:, 0]], np.cross(v[t[:, 1]], v[t[:, 2]])).sum() / 6)


def test_clustering_keeps_a_mesh_shape_and_winding_with_fewer_triangles_and_vertices():
    v, t, n = sphere()
    cv, ct, cn = cluster_mesh(v, t, n, 0.2)
    assert len(ct) < len(t) / 5 and len(cv) < len(v) / 50  # indexed: a vertex shared
    assert np.allclose(np.linalg.norm(cv, axis=1), 1, atol=0.1)  # on the sphere still
    assert np.allclose(np.linalg.norm(cn, axis=1), 1)
    assert np.einsum("ij,ij->i", cv, cn).min() > 0.9  # normals point out, as they did
    assert signed_volume(cv, ct) == pytest.approx(signed_volume(v, t), rel=0.15)  # winding
    assert len({tuple(sorted(x)) for x in ct.tolist()}) == len(ct)  # each triangle once
    assert (ct[:, 0] != ct[:, 1]).all() and (ct[:, 1] != ct[:, 2]).all()


def grid(width: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A flat, textured grid of 1 m squares at z = -0.9, its UVs affine in x, y, as
    ManiSkill's build_ground makes the ground: (vertices, triangles, normals, uvs)."""
    xs = np.arange(width + 1) - width / 2
    xy = np.stack(np.meshgrid(xs, xs, indexing="ij"), -1).reshape(-1, 2)
    v = np.c_[xy, np.full(len(xy), -0.9)]
    k = np.arange(width * (width + 1)).reshape(width, width + 1)[:, :-1].reshape(-1)
    t = np.concatenate([np.c_[k, k + width + 1, k + width + 2], np.c_[k, k + width + 2, k + 1]])
    return v, t, np.tile([0.0, 0.0, 1.0], (len(v), 1)), xy / 4 + 0.5


def test_a_flat_grid_is_drawn_as_the_quad_it_spans_with_its_texture_mapping():
    v, t, n, uv = grid()
    quad, tri, normals, quad_uv = flat_quad(v, t, n, uv)
    assert len(tri) == 2 and np.allclose(normals, [0, 0, 1])
    assert np.allclose(quad[:, 2], -0.9) and np.ptp(quad[:, 0]) == np.ptp(quad[:, 1]) == 10
    assert np.allclose(quad_uv, quad[:, :2] / 4 + 0.5)  # the grid's UVs at its corners
    cross = np.cross(quad[tri[:, 1]] - quad[tri[:, 0]], quad[tri[:, 2]] - quad[tri[:, 0]])
    grid_cross = np.cross(v[t[0, 1]] - v[t[0, 0]], v[t[0, 2]] - v[t[0, 0]])
    assert (np.sign(cross[:, 2]) == np.sign(grid_cross[2])).all()  # its winding, its side


def test_a_mesh_that_is_not_one_flat_rectangle_is_kept():
    v, t, n, uv = grid()
    bumpy = v.copy()
    bumpy[5, 2] += 0.01
    assert flat_quad(bumpy, t, n, uv) is None
    assert flat_quad(v, t[1:], n, uv) is None  # a hole
    assert flat_quad(v, t, n, uv**2) is None  # a texture mapping a quad would not keep


def colour_counts(image: np.ndarray) -> dict[str, int]:
    """Pixels of the scene's colours: the red and green cubes, the arm's light grey and the
    table's wood."""
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return {
        "red": int(((r > 120) & (g < 60) & (b < 60)).sum()),
        "green": int(((g > 120) & (r < 80) & (b < 80)).sum()),
        "grey": int(((r > 140) & (abs(r - b) < 25) & (abs(r - g) < 25)).sum()),
        "wood": int(((r > 120) & (r - b > 60) & (g > 60)).sum()),
    }


def neutral(image: np.ndarray) -> np.ndarray:
    """Where ``image`` is a grey, neither dark nor coloured: the arm, the hand, the ground."""
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return (abs(r - b) < 25) & (abs(r - g) < 25) & (r > 60)


@pytest.mark.sim
def test_lean_pictures_of_a_stored_state_are_the_scene():
    from mimicgen_pipe import backends
    from mimicgen_pipe.backends.maniskill.render import Renderer

    env = backends.make_env("maniskill", "stack_cube", "panda")
    env.reset(seed=0, variant="D0")
    state = env.get_state()
    env.close()
    lean = Renderer("stack_cube", "panda", 84, 84, CAMERAS)
    full = Renderer("stack_cube", "panda", 84, 84, CAMERAS, lean=False, shader="minimal")
    bodies = lean._env.unwrapped.scene.sub_scenes[0].render_system.render_bodies
    arm = [b for b in bodies if b.entity.name.startswith("panda_")]
    assert sum(len(p.triangles) for b in arm for s in b.render_shapes for p in s.parts) < 20000
    pictures, reference = lean.images(state), full.images(state)
    lean.close()
    full.close()
    for camera in CAMERAS:
        image, ref = pictures[camera], reference[camera]
        assert image.shape == (84, 84, 3) and image.dtype == np.uint8
        diff = np.abs(image.astype(int) - ref)
        # the full picture's colours, less its specular light on the wood
        assert diff.mean() < 22, (camera, diff.mean())
        # the arm, the hand and the ground as the full picture shades them: the lean meshes'
        # shape, normals and winding (flipped normals, or a 60 mm cell, give over 6)
        assert diff[neutral(ref)].mean() < 5, (camera, diff[neutral(ref)].mean())
        counts, expected = colour_counts(image), colour_counts(ref)
        for colour, n in expected.items():
            assert abs(counts[colour] - n) <= max(10, 0.1 * n), (camera, colour, counts)
    at = colour_counts(pictures["agentview"])
    assert at["red"] >= 10 and at["green"] >= 10  # both cubes
    assert at["grey"] >= 500 and at["wood"] >= 2000  # the arm on the table
    # the hand's fingers at the wrist camera's bottom edge, over the table
    wrist = colour_counts(pictures["eye_in_hand"][60:])
    assert wrist["grey"] >= 100 and colour_counts(pictures["eye_in_hand"])["wood"] >= 4000
