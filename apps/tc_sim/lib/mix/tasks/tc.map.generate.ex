defmodule Mix.Tasks.Tc.Map.Generate do
  @shortdoc "Draws a building-like map_server map: mix tc.map.generate --seed S --out PATH.yaml"
  @moduledoc """
  Draws a building-like world (`ThinkingCap.Sim.Buildings`: rooms, doors
  0.8–1.0 m wide, corridors, furniture, outer walls, 5 cm cells) and saves
  it as a ROS `map_server` map, the YAML at `--out` and the PGM beside it.

      mix tc.map.generate --seed 7 --out tmp/office7.yaml [--size 30x20]

  `--size WxH` is the building's size in metres (default 30x20). The same
  seed draws the same map. It prints what it drew and a free start point
  from which every free cell is reachable.
  """
  use Mix.Task

  alias ThinkingCap.Sim.Buildings

  @impl true
  def run(args) do
    {opts, rest, invalid} =
      OptionParser.parse(args, strict: [seed: :integer, out: :string, size: :string])

    cond do
      invalid != [] ->
        Mix.raise("tc.map.generate: bad option #{inspect(hd(invalid))}; #{usage()}")

      rest != [] ->
        Mix.raise("tc.map.generate: unexpected #{inspect(hd(rest))}; #{usage()}")

      opts[:out] == nil ->
        Mix.raise("tc.map.generate: give --out PATH.yaml; #{usage()}")

      Path.extname(opts[:out]) not in [".yaml", ".yml"] ->
        Mix.raise("tc.map.generate: --out #{opts[:out]} must name a .yaml file")

      true ->
        generate(opts)
    end
  end

  defp generate(opts) do
    size =
      case Buildings.parse_size(opts[:size] || "30x20") do
        {:ok, size} -> size
        {:error, message} -> Mix.raise("tc.map.generate: --#{message}")
      end

    with {:ok, building} <- Buildings.generate(seed: opts[:seed] || 1, size: size),
         :ok <- Buildings.save(building, opts[:out]) do
      %{map: map, start: {sx, sy}} = building

      Mix.shell().info(
        "tc.map.generate: #{opts[:out]} (#{map.width} x #{map.height} cells of " <>
          "#{map.resolution} m): #{length(building.rooms)} rooms, " <>
          "#{length(building.corridors)} corridors, #{length(building.doors)} doors, " <>
          "#{length(building.furniture)} pieces of furniture; start " <>
          "(#{Float.round(sx, 2)}, #{Float.round(sy, 2)})"
      )
    else
      {:error, message} -> Mix.raise("tc.map.generate: #{message}")
    end
  end

  defp usage, do: "usage: mix tc.map.generate --seed S --out PATH.yaml [--size WxH]"
end
