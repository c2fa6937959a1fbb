"""Two-player board games (pgx's) and the references that learned players are measured against:
an exact tic-tac-toe solver (tic_tac_toe_minimax), pure MCTS with random rollouts for any pgx
game (rollout_mcts), a match runner with win/draw/loss tables and Elo (match, elo), those
opponents by name (opponents), and frames of tic-tac-toe and Connect Four positions for GIFs
(draw).

Nothing here is imported by ``rl_jax.envs`` itself: importing pgx and mctx is left to those who
play games."""
