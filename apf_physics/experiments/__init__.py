"""Running planners over worlds and reporting: rollouts through the engine (``rollout``), episodes
and tables (``evaluate``), generated sets (``worldsets``), MovingAI scenarios (``movingai``) and
campaigns on Ray (``campaign``)."""
