"""Random masked actions on the default scenario (aot1 over Zenoh, one process per role)."""

from rich.progress import track

from env import ZenohEdgeEnv

env = ZenohEdgeEnv(max_steps=200)
observations, infos = env.reset(seed=42)
total = dict.fromkeys(env.possible_agents, 0.0)
for _ in track(range(env.max_steps), description="one episode"):  # a progress bar on a terminal
    actions = {agent: env.action_space(agent).sample(observations[agent]["action_mask"]) for agent in env.agents}
    observations, rewards, terminations, truncations, infos = env.step(actions)
    for agent, reward in rewards.items():
        total[agent] += reward

episode = infos[env.possible_agents[0]]["episode"]
print(f"{episode['ticks']} ticks: {episode['totals']['completed']} tasks completed, "
      f"{episode['totals']['dropped']['total']} dropped, mean response {episode['response_time']['mean']:.1f} s")
print("return per agent:", {agent: round(value) for agent, value in total.items()})
env.close()
